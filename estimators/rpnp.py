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

An optional Levenberg-Marquardt polish on the reprojection error (``refine=True``, from
:mod:`~eaglemission.estimators.pnp_refine`, shared with the OpenCV solvers) is off by default.
:class:`RPnPEstimator` (plugin ``rpnp``) applies it to a detection's four corners with the
target's top face as the model (see :mod:`eaglemission.estimators.correspondence`).

References
----------
.. [1] S. Li, C. Xu, M. Xie, "A Robust O(n) Solution to the Perspective-n-Point Problem",
   IEEE TPAMI 34(7):1444-1450, 2012. DOI: 10.1109/TPAMI.2012.41
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, ClassVar, Literal

import cv2
import numpy as np
from eaglemission.estimators.corner_plugin import CornerPnPConfig, CornerPnPEstimator
from eaglemission.estimators.pnp_refine import (
    refine_pose,
    reprojection_errors,
)
from numpy.typing import ArrayLike, NDArray

from eaglemission.kernels import lazy_kernel
from eaglemission.types import EstimationFailed, Mat3, PoseEstimate

if TYPE_CHECKING:
    from eaglemission.config import TargetConfig

__all__ = ["rpnp", "refine_pose", "reprojection_errors", "RPnPEstimator", "RPnPConfig"]

_IMAG_TOL = 1e-3  # |imag| / max|real| above which a root is not real (as in the reference code)


# ---------------------------------------------------------------------------------------------
# Small helpers
# ---------------------------------------------------------------------------------------------
def _frame_from_axis(x: NDArray[np.float64]) -> Mat3:
    """A right-handed frame whose first column is the unit vector ``x``; the auxiliary axis is
    chosen by comparing the components of ``x`` (as the reference implementation does)."""
    x0, x1, x2 = float(x[0]), float(x[1]), float(x[2])
    if abs(x1) < abs(x2):
        # z = x cross (0, 1, 0), y = z cross x
        z0, z1, z2 = -x2, 0.0, x0
        nz = math.sqrt(z0 * z0 + z2 * z2)
        z0, z2 = z0 / nz, z2 / nz
        y0, y1, y2 = z1 * x2 - z2 * x1, z2 * x0 - z0 * x2, z0 * x1 - z1 * x0
    else:
        # y = (0, 0, 1) cross x, z = x cross y
        y0, y1, y2 = -x1, x0, 0.0
        ny = math.sqrt(y0 * y0 + y1 * y1)
        y0, y1 = y0 / ny, y1 / ny
        z0, z1, z2 = x1 * y2 - x2 * y1, x2 * y0 - x0 * y2, x0 * y1 - x1 * y0
    ny = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    nz = math.sqrt(z0 * z0 + z1 * z1 + z2 * z2)
    return np.array([[x0, y0 / ny, z0 / nz], [x1, y1 / ny, z1 / nz], [x2, y2 / ny, z2 / nz]])


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


def _spread_rank(points: NDArray[np.float64], tol: float) -> int:
    """Numerical rank (0..dim) of a 2-D or 3-D point cloud's spread, from the invariants of its
    scatter matrix (no LAPACK call): rank >= 1 if the trace is positive, >= 2 if the sum of the
    2x2 principal minors (l1 l2 + l1 l3 + l2 l3) is not negligible against trace^2."""
    c = points - points.sum(axis=0) / points.shape[0]
    S = c.T @ c
    tr = float(np.trace(S))
    if not tr > 0:
        return 0
    if S.shape[0] == 2:
        m2 = float(S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0])
    else:
        m2 = float(S[0, 0] * S[1, 1] - S[0, 1] ** 2 + S[0, 0] * S[2, 2] - S[0, 2] ** 2
                   + S[1, 1] * S[2, 2] - S[1, 2] ** 2)
    return 1 if m2 <= tol * tr * tr else 2


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
    # eigvals gives a real array when every eigenvalue is real
    roots: NDArray[np.floating[Any]] | NDArray[np.complexfloating[Any, Any]]
    if p.size == 2:
        roots = np.array([-p[1] / p[0]], dtype=np.complex128)
    else:
        # np.roots without its input checks: eigenvalues of the companion matrix.
        comp = np.diag(np.ones(p.size - 2), -1)
        comp[0, :] = -p[1:] / p[0]
        roots = np.linalg.eigvals(comp)
    maxreal = float(np.abs(roots.real).max())
    if maxreal > 0:
        roots = roots[np.abs(roots.imag) / maxreal <= _IMAG_TOL]
    else:
        roots = roots[np.abs(roots.imag) <= _IMAG_TOL]
    t = np.asarray(roots.real, dtype=np.float64)  # a view of the roots: no copy
    dp = np.polyder(p)
    return t[np.polyval(dp, t) > 0]


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
    backend: Literal["numba", "numpy"] = "numba",
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
    backend : {"numba", "numpy"}
        The compiled kernel (default; falls back to numpy if numba is unavailable) or the
        vectorised numpy reference. Both compute the same thing (tested).

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
    if _spread_rank(X, 1e-14) < 2:
        return EstimationFailed("rpnp: object points are coincident or collinear")
    if _spread_rank(uv, 1e-14) < 2:
        return EstimationFailed(
            "rpnp: image points are coincident or collinear (object plane through the camera centre?)")
    # 1. Rotation axis from a point pair.
    if pair == "longest":
        i1, i2 = _choose_pair_longest(uv)
    elif pair == "random":
        gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(
            0 if rng is None else rng)
        i1, i2 = _choose_pair_random(uv, gen)
    else:
        raise ValueError(f"pair: must be 'longest' or 'random', got {pair!r}")
    with np.errstate(all="ignore"):
        try:
            if backend == "numba" and _kernel() is not None:
                result = _rpnp_numba(X, uv, i1, i2, refine=refine, return_all=return_all)
            else:
                result = _rpnp_numpy(X, uv, i1, i2, refine=refine, return_all=return_all)
        except np.linalg.LinAlgError as exc:
            return EstimationFailed(f"rpnp: linear algebra failed ({exc})")
    return result


# the compiled RPnP (loaded on first use; None: numpy reference)
_kernel = lazy_kernel("eaglemission.estimators._rpnp_kernel", "rpnp_core")


_STATUS = {
    1: "rpnp: the chosen point pair is coincident in the object frame",
    2: "rpnp: the P3P polynomial is not finite (degenerate geometry)",
    3: "rpnp: the cost polynomial has no real local minimum",
    4: "rpnp: the linear system has no finite solution",
}


def _finish(
    Rs: NDArray[np.float64], ts: NDArray[np.float64], err: NDArray[np.float64],
    XXw: NDArray[np.float64], xx: NDArray[np.float64], refine: bool, return_all: bool,
    backend: Literal["numba", "numpy"] = "numba",
) -> PoseEstimate | EstimationFailed:
    valid = np.isfinite(err) & np.isfinite(Rs).all(axis=(1, 2)) & np.isfinite(ts).all(axis=1)
    if not valid.any():
        return EstimationFailed("rpnp: every candidate pose puts points behind the camera")
    order = [int(k) for k in np.argsort(np.where(valid, err, np.inf)) if valid[k]]
    best = order[0]
    R, t = Rs[best], ts[best]
    if refine:
        R, t = refine_pose(R, t, XXw, xx, backend=backend)
        e = float(reprojection_errors(R, t, XXw, xx).mean())
    else:
        e = float(err[best])
    if not math.isfinite(e):
        return EstimationFailed("rpnp: the chosen pose puts points behind the camera")
    candidates = tuple((Rs[k], ts[k]) for k in order) if return_all else ()
    if return_all and refine:
        candidates = ((R, t),) + candidates[1:]
    return PoseEstimate(R=R, t_m=t, reprojection_error=e, candidates=candidates)


def _rpnp_numba(
    XXw: NDArray[np.float64], xx: NDArray[np.float64], i1: int, i2: int, *, refine: bool,
    return_all: bool,
) -> PoseEstimate | EstimationFailed:
    status, Rs, ts, err = _kernel()(np.ascontiguousarray(XXw), np.ascontiguousarray(xx), i1, i2)
    if status:
        return EstimationFailed(_STATUS[int(status)])
    return _finish(Rs, ts, err, XXw, xx, refine, return_all)


def _rpnp_numpy(
    XXw: NDArray[np.float64], xx: NDArray[np.float64], i1: int, i2: int, *, refine: bool,
    return_all: bool,
) -> PoseEstimate | EstimationFailed:
    n = XXw.shape[0]
    xv = np.empty((n, 3))
    xv[:, :2] = xx
    xv[:, 2] = 1.0
    xv /= np.sqrt(np.einsum("ij,ij->i", xv, xv))[:, None]
    p1, p2 = XXw[i1], XXw[i2]
    d12 = p2 - p1
    D1 = math.sqrt(float(d12 @ d12))
    centred = XXw - XXw.sum(axis=0) / n
    scale = math.sqrt(float(np.einsum("ij,ij->i", centred, centred).max()))
    if not D1 > 1e-12 * max(scale, 1e-300):
        return EstimationFailed("rpnp: the chosen point pair is coincident in the object frame")
    p0 = (p1 + p2) / 2.0
    Ro = _frame_from_axis(d12 / D1)
    XX = (XXw - p0) @ Ro  # object points in the pair's frame (x along P_i1 -> P_i2)

    # 2. P3P quartics of the n - 2 triplets and the degree-7 polynomial.
    v1, v2 = xv[i1], xv[i2]
    cg1 = float(v1 @ v2)
    idx = np.ones(n, dtype=bool)
    idx[i1] = False
    idx[i2] = False
    vi = xv[idx]
    cg2 = vi @ v1
    cg3 = vi @ v2
    e2 = XX[idx] - XX[i1]
    e3 = XX[idx] - XX[i2]
    D2 = np.sqrt(np.einsum("ij,ij->i", e2, e2))
    D3 = np.sqrt(np.einsum("ij,ij->i", e3, e3))
    quartics = p3p_quartics(cg1, cg2, cg3, D1, D2, D3)
    poly7 = cost_derivative_poly7(quartics)
    if not np.isfinite(poly7).all():
        return EstimationFailed("rpnp: the P3P polynomial is not finite (degenerate geometry)")

    # 3. Local minima of the cost.
    t2s = _local_minima(poly7)
    if t2s.size == 0:
        return EstimationFailed("rpnp: the cost polynomial has no real local minimum")

    # 4. Per root: the rotation axis in the camera frame, then (c, s, t) from a 2n x 6 system,
    #    all roots at once.
    axes = np.outer(cg1 + t2s, v2) - v1
    norms = np.sqrt(np.einsum("ij,ij->i", axes, axes))
    keep = norms > 1e-12
    if not keep.any():
        return EstimationFailed("rpnp: degenerate rotation axis")
    axes = axes[keep] / norms[keep, None]
    Rxs = np.stack([_frame_from_axis(a) for a in axes])  # (m, 3, 3), columns x, y, z
    u = xx[:, 0]
    v = xx[:, 1]
    xi, yi, zi = XX[:, 0], XX[:, 1], XX[:, 2]
    # X_c = M e_x xi + c (M e_y yi + M e_z zi) + s (M e_z yi - M e_y zi) + t  (M = Rx)
    My, Mz = Rxs[:, None, :, 1], Rxs[:, None, :, 2]
    A = My * yi[None, :, None] + Mz * zi[None, :, None]  # (m, n, 3)
    B = Mz * yi[None, :, None] - My * zi[None, :, None]
    C = Rxs[:, None, :, 0] * xi[None, :, None]
    m = Rxs.shape[0]
    ones = np.ones((m, n))
    zeros = np.zeros((m, n))
    Du = np.stack((A[..., 0] - u * A[..., 2], B[..., 0] - u * B[..., 2], ones, zeros,
                   -u * ones, C[..., 0] - u * C[..., 2]), axis=2)
    Dv = np.stack((A[..., 1] - v * A[..., 2], B[..., 1] - v * B[..., 2], zeros, ones,
                   -v * ones, C[..., 1] - v * C[..., 2]), axis=2)
    D = np.concatenate((Du, Dv), axis=1)  # (m, 2n, 6)
    DTD = np.matmul(D.transpose(0, 2, 1), D)
    _, V = np.linalg.eigh(DTD)
    sol = V[:, :, 0]
    last = sol[:, 5]
    ok = np.abs(last) > 1e-300
    if not ok.any():
        return EstimationFailed("rpnp: the linear system has no finite solution")
    sol = sol[ok] / last[ok, None]
    A, B, C = A[ok], B[ok], C[ok]

    # 5. Final pose of each candidate by scaled Procrustes (batched); smallest reprojection error.
    Xcs = C + sol[:, None, 0:1] * A + sol[:, None, 1:2] * B + sol[:, None, 2:5]
    depth = np.sqrt(np.einsum("mij,mij->mi", Xcs, Xcs))
    XXc = xv[None, :, :] * depth[:, :, None]
    Rs, ts = _umeyama_batch(XXw, XXc)
    Xc = np.matmul(XXw[None], Rs.transpose(0, 2, 1)) + ts[:, None, :]
    z = Xc[..., 2]
    proj = Xc[..., :2] / z[..., None]
    diff = proj - xx[None]
    err = np.sqrt(np.einsum("mij,mij->mi", diff, diff)).mean(axis=1)
    err = np.where((z > 0).all(axis=1), err, np.inf)
    return _finish(Rs, ts, err, XXw, xx, refine, return_all, backend="numpy")


def _umeyama_batch(obj: NDArray[np.float64], cams: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Scaled Procrustes (Umeyama) of m point sets at once: ``obj`` (n, 3), ``cams`` (m, n, 3);
    returns R (m, 3, 3), t (m, 3) with ``cams[k] ~ s_k R[k] obj + t[k]`` fitted, where
    ``t = mean(cam) - s R mean(obj)`` (the reference ``calcampose``)."""
    n = obj.shape[0]
    mx = obj.sum(axis=0) / n
    my = cams.sum(axis=1) / n
    X = obj - mx
    Y = cams - my[:, None, :]
    sigma_x2 = float(np.einsum("ij,ij->", X, X)) / n
    U, d, Vt = np.linalg.svd(np.matmul(Y.transpose(0, 2, 1), X) / n)
    det = np.linalg.det(np.matmul(U, Vt))
    sign = np.where(det < 0, -1.0, 1.0)
    U[:, :, 2] *= sign[:, None]
    d = d.copy()
    d[:, 2] *= sign
    R = np.matmul(U, Vt)
    scale = d.sum(axis=1) / sigma_x2 if sigma_x2 > 0 else np.ones(len(d))
    t = my - scale[:, None] * (R @ mx)
    return R, t


# ---------------------------------------------------------------------------------------------
# Plugin
# ---------------------------------------------------------------------------------------------
class RPnPConfig(CornerPnPConfig):
    """Params of the ``rpnp`` estimator plugin."""

    pair: Literal["longest", "random"] = "longest"
    seed: int = 0
    refine: bool = False


class RPnPEstimator(CornerPnPEstimator):
    """Plugin ``rpnp``: target pose from a detection's 4 corners (top face as the model)."""

    Config: ClassVar[type[RPnPConfig]] = RPnPConfig
    description: ClassVar[str] = "RPnP (Li, Xu, Xie 2012) on the target's top face from the MBR corners"

    def __init__(self, config: RPnPConfig | None = None, *, target: TargetConfig | None = None,
                 **context: object) -> None:
        self.config: RPnPConfig = config if config is not None else RPnPConfig()
        cfg = self.config
        rng = np.random.default_rng(cfg.seed)

        def solver(obj: NDArray[np.float64], nrm: NDArray[np.float64]) -> PoseEstimate | EstimationFailed:
            return rpnp(obj, nrm, pair=cfg.pair, rng=rng, refine=cfg.refine, return_all=True)

        super().__init__(solver, cfg, target=target, source="rpnp")
