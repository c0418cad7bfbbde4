"""RPnP: the robust O(n) Perspective-n-Point solver of Li, Xu and Xie (TPAMI 2012).

The pure function :func:`rpnp` implements the whole algorithm:

1. a rotation axis from one point pair (by default the longest projected edge over all pairs,
   the authors' deterministic "RPnP*"; or the original random sampling of n pairs, through a
   seeded generator),
2. the n - 2 P3P constraints of the triplets (pair + one other point), each a quartic in the
   unknown ``t`` (depth of the second point of the pair relative to the first), whose sum of
   squares is the cost; its derivative is the seventh-degree polynomial,
3. the real roots of that polynomial that are local minima of the cost,
4. for each root, the rotation about the axis and the translation from a 2n x 6 linear system
   (eigenvector of the smallest eigenvalue of ``D^T D``),
5. the final pose of each candidate by a scaled Procrustes alignment (Umeyama) of the object
   points with the points pushed onto their viewing rays, and the choice of the candidate with
   the smallest mean reprojection error in normalised coordinates.

An optional Levenberg-Marquardt polish on the reprojection error (``refine=True``) is off by
default. :class:`RPnPEstimator` (plugin ``rpnp``) applies it to a detection's four corners with
the target's top face as the model (see :mod:`eaglemission.estimators.correspondence`).

References
----------
.. [1] S. Li, C. Xu, M. Xie, "A Robust O(n) Solution to the Perspective-n-Point Problem",
   IEEE TPAMI 34(7):1444-1450, 2012. DOI: 10.1109/TPAMI.2012.41
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field

from eaglemission.types import EstimationFailed, Mat3, PoseEstimate, Vec3

__all__ = ["rpnp", "refine_pose", "reprojection_errors", "RPnPEstimator", "RPnPConfig"]

_IMAG_TOL = 1e-3  # |imag| / max|real| above which a root is not real (as in the reference code)


# ---------------------------------------------------------------------------------------------
# Small helpers
# ---------------------------------------------------------------------------------------------
def _frame_from_axis(x: NDArray[np.float64]) -> Mat3:
    """A right-handed frame whose first column is the unit vector ``x``; the auxiliary axis is
    chosen by comparing the components of ``x`` (as the reference implementation does)."""
    if abs(x[1]) < abs(x[2]):
        z = np.cross(x, (0.0, 1.0, 0.0))
        z /= np.linalg.norm(z)
        y = np.cross(z, x)
    else:
        y = np.cross((0.0, 0.0, 1.0), x)
        y /= np.linalg.norm(y)
        z = np.cross(x, y)
    y /= np.linalg.norm(y)
    z /= np.linalg.norm(z)
    return np.column_stack((x, y, z))


def _umeyama(obj: NDArray[np.float64], cam: NDArray[np.float64]) -> tuple[Mat3, Vec3]:
    """Scaled Procrustes: R, t with ``cam ~ s R obj + t`` fitted, returned as (R, t) where
    ``t = mean(cam) - s R mean(obj)`` (the reference ``calcampose``)."""
    mx = obj.mean(axis=0)
    my = cam.mean(axis=0)
    X = obj - mx
    Y = cam - my
    n = obj.shape[0]
    sigma_x2 = float((X * X).sum()) / n
    sxy = (Y.T @ X) / n
    U, d, Vt = np.linalg.svd(sxy)
    S = np.ones(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2] = -1.0
    R = (U * S) @ Vt
    scale = float((d * S).sum()) / sigma_x2 if sigma_x2 > 0 else 1.0
    t = my - scale * (R @ mx)
    return R, t


def reprojection_errors(
    R: Mat3, t: Vec3, object_points: NDArray[np.float64], normalized_points: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Per-point reprojection error in normalised image units (inf behind the camera)."""
    Xc = object_points @ R.T + t
    z = Xc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        proj = Xc[:, :2] / z[:, None]
        e = np.linalg.norm(proj - normalized_points, axis=1)
    e[~(z > 0)] = np.inf
    return e


def _choose_pair_longest(uv: NDArray[np.float64]) -> tuple[int, int]:
    """Indices of the two image points farthest apart (the longest projected edge over all
    pairs), in O(n log n): the diameter of a point set is attained by convex hull vertices."""
    n = uv.shape[0]
    if n <= 16:
        cand = np.arange(n)
    else:
        scale = float(np.abs(uv).max()) or 1.0
        hull = cv2.convexHull((uv / scale).astype(np.float32), returnPoints=False)
        cand = np.unique(hull.reshape(-1)) if hull is not None else np.arange(n)
        if cand.size < 2:
            cand = np.arange(n)
    p = uv[cand]
    d2 = ((p[:, None, :] - p[None, :, :]) ** 2).sum(axis=2)
    k = int(np.argmax(d2))
    i, j = divmod(k, p.shape[0])
    return int(cand[i]), int(cand[j])


def _choose_pair_random(uv: NDArray[np.float64], rng: np.random.Generator) -> tuple[int, int]:
    """The original selection: n random pairs, keep the longest projected edge."""
    n = uv.shape[0]
    ij = rng.integers(0, n, size=(n, 2))
    ij = ij[ij[:, 0] != ij[:, 1]]
    if ij.shape[0] == 0:
        return 0, 1
    d2 = ((uv[ij[:, 0]] - uv[ij[:, 1]]) ** 2).sum(axis=1)
    k = int(np.argmax(d2))
    d01 = float(((uv[0] - uv[1]) ** 2).sum())
    if d2[k] <= d01:
        return 0, 1
    return int(ij[k, 0]), int(ij[k, 1])


def _degeneracy(points: NDArray[np.float64], rank_tol: float) -> int:
    """Numerical rank (0..dim) of a point cloud's spread."""
    c = points - points.mean(axis=0)
    s = np.linalg.svd(c, compute_uv=False)
    if s.size == 0 or s[0] <= 0:
        return 0
    return int((s > rank_tol * s[0]).sum())


# ---------------------------------------------------------------------------------------------
# The P3P quartics and the degree-7 polynomial
# ---------------------------------------------------------------------------------------------
def p3p_quartics(
    cg1: float, cg2: NDArray[np.float64], cg3: NDArray[np.float64],
    D1: float, D2: NDArray[np.float64], D3: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Coefficients (highest first, shape (n-2, 5)) of the quartic P3P constraint of each
    triplet (P_i1, P_i2, P_k) in ``t`` where the depths along the unit rays are
    ``d_i1 = 1``, ``d_i2 = cos(gamma_1) + t`` up to a common scale (Sec. 3.1 of [1]).

    ``cg1 = v_i1 . v_i2``, ``cg2 = v_i1 . v_k``, ``cg3 = v_i2 . v_k``; ``D1 = |P_i1 P_i2|``,
    ``D2 = |P_i1 P_k|``, ``D3 = |P_k P_i2|``.
    """
    sg1_2 = 1.0 - cg1 * cg1
    sg2_2 = 1.0 - cg2 * cg2
    A1 = (D2 / D1) ** 2
    A2 = A1 * sg1_2 - sg2_2
    A3 = cg2 * cg3 - cg1
    A4 = cg1 * cg3 - cg2
    A6 = (D3 * D3 - D1 * D1 - D2 * D2) / (2.0 * D1 * D1)
    A7 = 1.0 - cg1 * cg1 - cg2 * cg2 + cg1 * cg2 * cg3 + A6 * sg1_2
    return np.column_stack((
        A6 * A6 - A1 * cg3 * cg3,
        2.0 * (A3 * A6 - A1 * A4 * cg3),
        A3 * A3 + 2.0 * A6 * A7 - A1 * A4 * A4 - A2 * cg3 * cg3,
        2.0 * (A3 * A7 - A2 * A4 * cg3),
        A7 * A7 - A2 * A4 * A4,
    ))


def cost_derivative_poly7(quartics: NDArray[np.float64]) -> NDArray[np.float64]:
    """Coefficients (highest first, 8) of ``sum_k f_k(t) f_k'(t)``, half the derivative of the
    cost ``F(t) = sum_k f_k(t)^2`` of the n - 2 quartics ``f_k`` (Eq. (9)-(10) of [1])."""
    a, b, c, d, e = quartics.T
    return np.array([
        (4 * a * a).sum(),
        (7 * a * b).sum(),
        (6 * a * c + 3 * b * b).sum(),
        (5 * a * d + 5 * b * c).sum(),
        (4 * a * e + 4 * b * d + 2 * c * c).sum(),
        (3 * b * e + 3 * c * d).sum(),
        (2 * c * e + d * d).sum(),
        (d * e).sum(),
    ])


def _local_minima(poly7: NDArray[np.float64]) -> NDArray[np.float64]:
    """Real roots of the degree-7 polynomial where the cost has a minimum."""
    lead = np.flatnonzero(np.abs(poly7) > 0)
    if lead.size == 0:
        return np.empty(0)
    p = poly7[lead[0]:]
    if p.size < 2:
        return np.empty(0)
    roots = np.roots(p)
    if roots.size == 0:
        return np.empty(0)
    maxreal = float(np.abs(roots.real).max())
    if maxreal > 0:
        roots = roots[np.abs(roots.imag) / maxreal <= _IMAG_TOL]
    else:
        roots = roots[np.abs(roots.imag) <= _IMAG_TOL]
    t = roots.real
    dp = np.polyder(p)
    return t[np.polyval(dp, t) > 0]


# ---------------------------------------------------------------------------------------------
# Refinement
# ---------------------------------------------------------------------------------------------
def _skew_batch(v: NDArray[np.float64]) -> NDArray[np.float64]:
    z = np.zeros(v.shape[0])
    return np.stack((
        np.stack((z, -v[:, 2], v[:, 1]), axis=1),
        np.stack((v[:, 2], z, -v[:, 0]), axis=1),
        np.stack((-v[:, 1], v[:, 0], z), axis=1),
    ), axis=1)


def _rodrigues(w: NDArray[np.float64]) -> Mat3:
    theta = float(np.linalg.norm(w))
    if theta < 1e-12:
        K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
        return np.eye(3) + K
    k = w / theta
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(theta) * K + (1 - math.cos(theta)) * (K @ K)


def refine_pose(
    R: Mat3, t: Vec3, object_points: NDArray[np.float64], normalized_points: NDArray[np.float64],
    *, max_iterations: int = 10, tol: float = 1e-12,
) -> tuple[Mat3, Vec3]:
    """Levenberg-Marquardt on the reprojection error in normalised coordinates.

    Parameterised by a left-multiplied rotation increment ``R <- exp([w]) R`` and ``t <- t + dt``;
    the Jacobian is analytic and vectorised over the points. Returns the input pose unchanged if
    no step lowers the error (e.g. points behind the camera).
    """
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


# ---------------------------------------------------------------------------------------------
# RPnP
# ---------------------------------------------------------------------------------------------
def rpnp(
    object_points: ArrayLike,
    normalized_points: ArrayLike,
    *,
    pair: Literal["longest", "random"] = "longest",
    rng: np.random.Generator | int | None = None,
    refine: bool = False,
    return_all: bool = False,
) -> PoseEstimate | EstimationFailed:
    """Pose of an object from n >= 4 point correspondences, RPnP of [1].

    Parameters
    ----------
    object_points : array_like of shape (n, 3)
        Points in the object frame (any unit; ``t`` comes back in that unit).
    normalized_points : array_like of shape (n, 2)
        Undistorted normalised image coordinates ``((u - cx)/fx, (v - cy)/fy)``.
    pair : {"longest", "random"}
        Choice of the point pair that defines the rotation axis: ``"longest"`` (default,
        deterministic, RPnP*) takes the longest projected edge over all pairs; ``"random"`` is
        the original (n random pairs, longest kept), drawn from ``rng``.
    rng : numpy Generator or int seed, optional
        Random stream for ``pair="random"`` (default seed 0, so results are reproducible).
    refine : bool
        Polish the chosen pose by Levenberg-Marquardt on the reprojection error (off by default).
    return_all : bool
        Put every candidate (one per local minimum of the cost), best first, in
        ``PoseEstimate.candidates``.

    Returns
    -------
    PoseEstimate or EstimationFailed
        ``R``, ``t_m`` with ``X_c = R @ X_o + t``; ``reprojection_error`` is the mean error in
        normalised image units. Degenerate input (n < 4, NaN, coincident or collinear points,
        no candidate in front of the camera) gives an :class:`EstimationFailed` with the reason.

    Raises
    ------
    ValueError
        If the arrays do not have shapes (n, 3) and (n, 2) with the same n (misuse).
    """
    X = np.asarray(object_points, dtype=np.float64)
    uv = np.asarray(normalized_points, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3:
        raise ValueError(f"object_points: must have shape (n, 3), got {X.shape}")
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise ValueError(f"normalized_points: must have shape (n, 2), got {uv.shape}")
    if X.shape[0] != uv.shape[0]:
        raise ValueError(
            f"object_points and normalized_points: need the same n, got {X.shape[0]} and {uv.shape[0]}")
    n = X.shape[0]
    if n < 4:
        return EstimationFailed(f"rpnp: needs at least 4 points, got {n}")
    if not (np.isfinite(X).all() and np.isfinite(uv).all()):
        return EstimationFailed("rpnp: input contains NaN or inf")
    if _degeneracy(X, 1e-9) < 2:
        return EstimationFailed("rpnp: object points are coincident or collinear")
    if _degeneracy(uv, 1e-9) < 2:
        return EstimationFailed(
            "rpnp: image points are coincident or collinear (object plane through the camera centre?)")
    with np.errstate(all="ignore"):
        try:
            result = _rpnp(X, uv, pair=pair, rng=rng, refine=refine, return_all=return_all)
        except np.linalg.LinAlgError as exc:
            return EstimationFailed(f"rpnp: linear algebra failed ({exc})")
    return result


def _rpnp(
    XXw: NDArray[np.float64], xx: NDArray[np.float64], *, pair: str,
    rng: np.random.Generator | int | None, refine: bool, return_all: bool,
) -> PoseEstimate | EstimationFailed:
    n = XXw.shape[0]
    xv = np.column_stack((xx, np.ones(n)))
    xv /= np.linalg.norm(xv, axis=1, keepdims=True)

    # 1. Rotation axis from a point pair.
    if pair == "longest":
        i1, i2 = _choose_pair_longest(xx)
    elif pair == "random":
        gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(
            0 if rng is None else rng)
        i1, i2 = _choose_pair_random(xx, gen)
    else:
        raise ValueError(f"pair: must be 'longest' or 'random', got {pair!r}")
    p1, p2 = XXw[i1], XXw[i2]
    D1 = float(np.linalg.norm(p2 - p1))
    scale = float(np.linalg.norm(XXw - XXw.mean(axis=0), axis=1).max())
    if not D1 > 1e-12 * max(scale, 1e-300):
        return EstimationFailed("rpnp: the chosen point pair is coincident in the object frame")
    p0 = (p1 + p2) / 2.0
    Ro = _frame_from_axis((p2 - p0) / np.linalg.norm(p2 - p0))
    XX = (XXw - p0) @ Ro  # object points in the pair's frame (x along P_i1 -> P_i2)

    # 2. P3P quartics of the n - 2 triplets and the degree-7 polynomial.
    v1, v2 = xv[i1], xv[i2]
    cg1 = float(v1 @ v2)
    idx = np.ones(n, dtype=bool)
    idx[[i1, i2]] = False
    vi = xv[idx]
    cg2 = vi @ v1
    cg3 = vi @ v2
    D2 = np.linalg.norm(XX[idx] - XX[i1], axis=1)
    D3 = np.linalg.norm(XX[idx] - XX[i2], axis=1)
    quartics = p3p_quartics(cg1, cg2, cg3, D1, D2, D3)
    poly7 = cost_derivative_poly7(quartics)
    if not np.isfinite(poly7).all():
        return EstimationFailed("rpnp: the P3P polynomial is not finite (degenerate geometry)")

    # 3. Local minima of the cost.
    t2s = _local_minima(poly7)
    if t2s.size == 0:
        return EstimationFailed("rpnp: the cost polynomial has no real local minimum")

    # 4. Per root: the rotation axis in the camera frame, then (c, s, t) from a 2n x 6 system.
    d2 = cg1 + t2s
    axes = v2[None, :] * d2[:, None] - v1[None, :]
    norms = np.linalg.norm(axes, axis=1)
    keep = norms > 1e-12
    axes = axes[keep] / norms[keep, None]
    if axes.shape[0] == 0:
        return EstimationFailed("rpnp: degenerate rotation axis")
    Rxs = np.stack([_frame_from_axis(a) for a in axes])  # (m, 3, 3)
    u = xx[:, 0]
    v = xx[:, 1]
    xi, yi, zi = XX[:, 0], XX[:, 1], XX[:, 2]
    # X_c = M e_x xi + c (M e_y yi + M e_z zi) + s (M e_z yi - M e_y zi) + t
    A = Rxs[:, None, :, 1] * yi[None, :, None] + Rxs[:, None, :, 2] * zi[None, :, None]  # (m,n,3)
    B = Rxs[:, None, :, 2] * yi[None, :, None] - Rxs[:, None, :, 1] * zi[None, :, None]
    C = Rxs[:, None, :, 0] * xi[None, :, None]
    m = Rxs.shape[0]
    D = np.zeros((m, n, 2, 6))
    D[:, :, 0, 0] = A[..., 0] - u * A[..., 2]
    D[:, :, 0, 1] = B[..., 0] - u * B[..., 2]
    D[:, :, 0, 2] = 1.0
    D[:, :, 0, 4] = -u
    D[:, :, 0, 5] = C[..., 0] - u * C[..., 2]
    D[:, :, 1, 0] = A[..., 1] - v * A[..., 2]
    D[:, :, 1, 1] = B[..., 1] - v * B[..., 2]
    D[:, :, 1, 3] = 1.0
    D[:, :, 1, 4] = -v
    D[:, :, 1, 5] = C[..., 1] - v * C[..., 2]
    D = D.reshape(m, 2 * n, 6)
    DTD = np.einsum("mki,mkj->mij", D, D)
    _, V = np.linalg.eigh(DTD)
    sol = V[:, :, 0]
    last = sol[:, 5]
    ok = np.abs(last) > 1e-300
    if not ok.any():
        return EstimationFailed("rpnp: the linear system has no finite solution")

    # 5. Final pose of each candidate by scaled Procrustes; keep the smallest reprojection error.
    cands: list[tuple[float, Mat3, Vec3]] = []
    for k in np.flatnonzero(ok):
        c, s, tx, ty, tz = sol[k, :5] / last[k]
        Xcs = C[k] + c * A[k] + s * B[k] + np.array([tx, ty, tz])
        depth = np.linalg.norm(Xcs, axis=1)
        XXc = xv * depth[:, None]
        R, t = _umeyama(XXw, XXc)
        if not (np.isfinite(R).all() and np.isfinite(t).all()):
            continue
        err = reprojection_errors(R, t, XXw, xx)
        cands.append((float(err.mean()), R, t))
    cands = [cd for cd in cands if math.isfinite(cd[0])]
    if not cands:
        return EstimationFailed("rpnp: every candidate pose puts points behind the camera")
    cands.sort(key=lambda cd: cd[0])
    _, R, t = cands[0]
    if refine:
        R, t = refine_pose(R, t, XXw, xx)
    err = float(reprojection_errors(R, t, XXw, xx).mean())
    if not math.isfinite(err):
        return EstimationFailed("rpnp: the chosen pose puts points behind the camera")
    candidates = tuple((cR, ct) for _, cR, ct in cands) if return_all else ()
    return PoseEstimate(R=R, t_m=t, reprojection_error=err, candidates=candidates)


# ---------------------------------------------------------------------------------------------
# Plugin
# ---------------------------------------------------------------------------------------------
class RPnPConfig(BaseModel):
    """Params of the ``rpnp`` estimator plugin."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    pair: Literal["longest", "random"] = "longest"
    seed: int = 0
    refine: bool = False
    mbr_correction: Literal["none", "box_fit"] = Field(
        "box_fit", description="correct the MBR-vs-top-face bias (docs/estimators.md)")
    max_reprojection_error_px: float = Field(
        8.0, gt=0, description="reject poses whose mean corner reprojection error is larger")
    previous_pose_weight_px_per_m: float = Field(
        20.0, ge=0, description="weight of the distance to the previous pose in the corner-order choice")
    std_m: float = Field(0.05, gt=0, description="reported 1-sigma position uncertainty at 1 m range")


class RPnPEstimator:
    """Plugin ``rpnp``: target pose from a detection's 4 corners (top face as the model)."""

    Config: ClassVar[type[BaseModel]] = RPnPConfig
    description: ClassVar[str] = "RPnP (Li, Xu, Xie 2012) on the target's top face from the MBR corners"

    def __init__(self, config: BaseModel | None = None, *, target: Any = None, **context: Any) -> None:
        from eaglemission.estimators.correspondence import CornerPoseEstimator

        self.config: Any = config if config is not None else RPnPConfig()
        cfg = self.config
        rng = np.random.default_rng(cfg.seed)

        def solver(obj: NDArray[np.float64], nrm: NDArray[np.float64]) -> PoseEstimate | EstimationFailed:
            return rpnp(obj, nrm, pair=cfg.pair, rng=rng, refine=cfg.refine, return_all=True)

        self._core = CornerPoseEstimator(
            solver=solver, target=target, source="rpnp", mbr_correction=cfg.mbr_correction,
            max_reprojection_error_px=cfg.max_reprojection_error_px,
            previous_pose_weight_px_per_m=cfg.previous_pose_weight_px_per_m, std_m=cfg.std_m)

    def reset(self) -> None:
        self._core.reset()

    def estimate(self, detection: Any, view: Any) -> Any:
        return self._core.estimate(detection, view)
