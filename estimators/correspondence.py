"""From a detection's four MBR corners to the target's pose: model, corner order, MBR bias.

The target is a box (``TargetConfig``: ``length_m`` along its heading, ``width_m``, ``height_m``);
its **top face** is the PnP model, corners in the target frame (docs/conventions.md) ordered
(+L/2, -W/2), (+L/2, +W/2), (-L/2, +W/2), (-L/2, -W/2), z = 0, the box below it (0 <= z <= H,
z down).

Corner order. The detector's corners are clockwise on screen from the top-left corner. Seen from
above the model order is also clockwise, so the only assignments that keep the face's
orientation are the 4 cyclic shifts. Rule (:meth:`CornerPoseEstimator.candidates`): every shift x
every solver candidate is scored by

    score = mean reprojection error (px)
            + tilt_weight_px_per_deg * max(0, tilt_deg - tilt_free_deg)
            + previous_pose_weight_px_per_m * |position - previous position|   (if any)
            + yaw_weight_px_per_deg * |wrap(yaw - previous yaw)|               (if any)

where ``tilt_deg`` is the angle between the top face's normal (in NED, through the camera's
pose at exposure time) and the vertical: the target lies flat. Candidates with points behind the
camera or the top face turned away are dropped. A rectangle's shifts 0 and 2 (a square's 0..3)
give the same centre and fit equally: position is unaffected, and yaw goes to the one nearest the
previous yaw, else to the one in [-90, 90).

MBR bias. A box seen obliquely shows its side faces; a saliency MBR of a uniformly coloured box
bounds the whole silhouette, so "MBR corners = top-face corners" (the paper) biases the pose
(:func:`mbr_bias`; metres at 4-10 m, docs/estimators.md). ``mbr_correction="auto"`` (default)
refines the target's NED position and yaw (face kept horizontal) so that the minimum-area
rectangle of the projected region -- the box's silhouette, or the top face alone if that fits
better -- matches the detected MBR (Levenberg-Marquardt on the 8 corner residuals in pixels),
starting from the PnP pose and from the centre ray; ``"box_fit"`` uses the silhouette only;
``"none"`` is the paper's reading.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from numpy.typing import NDArray

from eaglemission.geometry import CameraModel, CameraMount, Pose, order_corners, rot_z, wrap_deg
from eaglemission.interfaces.estimator import CameraView
from eaglemission.types import (
    Detection,
    EstimationFailed,
    Mat3,
    PoseEstimate,
    TargetEstimate,
    Vec3,
)

if TYPE_CHECKING:
    from eaglemission.config import TargetConfig

Solver = Callable[[NDArray[np.float64], NDArray[np.float64]], PoseEstimate | EstimationFailed]


# ---------------------------------------------------------------------------------------------
# Model
# ---------------------------------------------------------------------------------------------
def top_face_model(length_m: float, width_m: float) -> NDArray[np.float64]:
    """(4, 3) top-face corners in the target frame, in the order of docs/conventions.md."""
    L, W = length_m / 2.0, width_m / 2.0
    return np.array([[L, -W, 0.0], [L, W, 0.0], [-L, W, 0.0], [-L, -W, 0.0]])


def box_corners(length_m: float, width_m: float, height_m: float) -> NDArray[np.float64]:
    """(8, 3) box corners in the target frame: the top face (z = 0), then the bottom (z = H)."""
    top = top_face_model(length_m, width_m)
    bottom = top.copy()
    bottom[:, 2] = height_m
    return np.vstack((top, bottom))


def project_box_mbr(
    model: CameraModel, R_ct: Mat3, t_ct: Vec3, length_m: float, width_m: float, height_m: float,
) -> NDArray[np.float64] | None:
    """MBR (``cv2.minAreaRect``) corners, ordered, of the box's silhouette in the image, or
    None if a corner is behind the camera. ``X_c = R_ct X_t + t_ct``."""
    pts = box_corners(length_m, width_m, height_m) @ R_ct.T + t_ct
    if not (pts[:, 2] > 1e-6).all():
        return None
    px = model.project(pts)
    if not np.isfinite(px).all():
        return None
    rect = cv2.minAreaRect(px.astype(np.float32))
    return order_corners(cv2.boxPoints(rect).astype(np.float64))


_PAIRS = np.array([(i, j) for i in range(8) for j in range(i + 1, 8)])


def min_area_rect_corners(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Corners (4, 2), ordered as :func:`order_corners`, of the minimum-area rectangle around
    up to 8 points, in float64 (``cv2.minAreaRect`` works in float32, whose ~1e-4 px noise keeps
    a least-squares fit from converging). The optimal rectangle has a side along a hull edge,
    so trying the direction of every point pair is enough."""
    p = np.asarray(points, dtype=np.float64)
    n = p.shape[0]
    pairs = _PAIRS[(_PAIRS[:, 1] < n)] if n <= 8 else np.array(
        [(i, j) for i in range(n) for j in range(i + 1, n)])
    d = p[pairs[:, 1]] - p[pairs[:, 0]]
    norm = np.hypot(d[:, 0], d[:, 1])
    ok = norm > 1e-12
    if not ok.any():
        return np.repeat(p[:1], 4, axis=0)
    ux = d[ok] / norm[ok, None]  # (k, 2) side directions
    uy = np.column_stack((-ux[:, 1], ux[:, 0]))
    a = p @ ux.T  # (n, k)
    b = p @ uy.T
    amin, amax, bmin, bmax = a.min(0), a.max(0), b.min(0), b.max(0)
    k = int(np.argmin((amax - amin) * (bmax - bmin)))
    e1, e2 = ux[k], uy[k]
    c = np.array([amin[k] * e1 + bmin[k] * e2, amax[k] * e1 + bmin[k] * e2,
                  amax[k] * e1 + bmax[k] * e2, amin[k] * e1 + bmax[k] * e2])
    return order_corners(c)


def project_top_face(model: CameraModel, R_ct: Mat3, t_ct: Vec3, length_m: float, width_m: float
                     ) -> NDArray[np.float64]:
    """(4, 2) pixels of the top-face corners, in model order (NaN behind the camera)."""
    return model.project(top_face_model(length_m, width_m) @ R_ct.T + t_ct)


# ---------------------------------------------------------------------------------------------
# Pose conversions
# ---------------------------------------------------------------------------------------------
def target_pose_in_camera(cam_ned: Pose, position_ned_m: Vec3, yaw_deg: float) -> tuple[Mat3, Vec3]:
    """Target (flat, at ``position_ned_m``, heading ``yaw_deg``) -> optical frame (R, t)."""
    R_nt = rot_z(math.radians(yaw_deg))
    R_ct = cam_ned.R.T @ R_nt
    t_ct = cam_ned.R.T @ (np.asarray(position_ned_m, dtype=np.float64) - cam_ned.t)
    return R_ct, t_ct


def target_ned_from_camera(cam_ned: Pose, R_ct: Mat3, t_ct: Vec3) -> tuple[Vec3, float, float]:
    """(position_ned_m, yaw_deg, tilt_deg) of a target pose given in the optical frame.

    ``tilt_deg`` is the angle of the target's z axis (its top face's downward normal) from NED
    down."""
    R_nt = cam_ned.R @ R_ct
    p = cam_ned.R @ t_ct + cam_ned.t
    # Heading of the target's x axis projected on the horizontal plane.
    yaw = math.degrees(math.atan2(R_nt[1, 0], R_nt[0, 0]))
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, float(R_nt[2, 2])))))
    return p, wrap_deg(yaw), tilt


# ---------------------------------------------------------------------------------------------
# Bias of the paper's "MBR corners = top-face corners"
# ---------------------------------------------------------------------------------------------
def mbr_bias(
    model: CameraModel, cam_ned: Pose, position_ned_m: Vec3, yaw_deg: float,
    length_m: float, width_m: float, height_m: float, solver: Solver,
) -> tuple[float, float] | None:
    """Position error (m) of the target estimated from the MBR of its projected box, without and
    with the box-fit correction; None if the box is not fully in front of the camera."""
    R_ct, t_ct = target_pose_in_camera(cam_ned, position_ned_m, yaw_deg)
    mbr = project_box_mbr(model, R_ct, t_ct, length_m, width_m, height_m)
    if mbr is None:
        return None
    est = CornerPoseEstimator(solver=solver, length_m=length_m, width_m=width_m,
                              height_m=height_m, mbr_correction="none")
    raw = est.solve_corners(mbr, model, cam_ned)
    est_fit = CornerPoseEstimator(solver=solver, length_m=length_m, width_m=width_m,
                                  height_m=height_m, mbr_correction="box_fit")
    fit = est_fit.solve_corners(mbr, model, cam_ned)
    if isinstance(raw, EstimationFailed) or isinstance(fit, EstimationFailed):
        return None
    truth = np.asarray(position_ned_m, dtype=np.float64)
    return (float(np.linalg.norm(raw.position_ned - truth)),
            float(np.linalg.norm(fit.position_ned - truth)))


# ---------------------------------------------------------------------------------------------
# Estimator core shared by the PnP plugins
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CornerSolution:
    """One hypothesis: corner shift, pose in the optical frame, its NED reading and score."""

    shift: int
    R_ct: Mat3
    t_ct: Vec3
    position_ned: Vec3
    yaw_deg: float
    tilt_deg: float
    error_px: float
    score: float

    def __bool__(self) -> bool:
        return True


class CornerPoseEstimator:
    """Corner order, solver, MBR correction and NED conversion for the PnP plugins.

    Keeps the previous accepted pose (position, yaw) for ``previous_pose_timeout_s`` to break
    ties between corner assignments; ``reset()`` forgets it.
    """

    def __init__(
        self, *, solver: Solver, target: TargetConfig | None = None, length_m: float | None = None,
        width_m: float | None = None, height_m: float | None = None, source: str = "pnp",
        mbr_correction: str = "auto", max_reprojection_error_px: float = 8.0,
        previous_pose_weight_px_per_m: float = 20.0, tilt_weight_px_per_deg: float = 0.5,
        tilt_free_deg: float = 10.0, yaw_weight_px_per_deg: float = 0.01,
        previous_pose_timeout_s: float = 2.0, std_m: float = 0.05, good_fit_px: float = 1.0,
        max_polished_starts: int = 3, warm_up: bool = False,
    ) -> None:
        if target is not None:
            length_m, width_m, height_m = target.length_m, target.width_m, target.height_m
        if length_m is None or width_m is None:
            raise ValueError("CornerPoseEstimator: needs target (TargetConfig) or length_m/width_m")
        self.length_m = float(length_m)
        self.width_m = float(width_m)
        self.height_m = float(height_m or 0.0)
        self.solver = solver
        self.source = source
        self.mbr_correction = mbr_correction
        self.max_reprojection_error_px = max_reprojection_error_px
        self.previous_pose_weight_px_per_m = previous_pose_weight_px_per_m
        self.tilt_weight_px_per_deg = tilt_weight_px_per_deg
        self.tilt_free_deg = tilt_free_deg
        self.yaw_weight_px_per_deg = yaw_weight_px_per_deg
        self.previous_pose_timeout_ns = int(previous_pose_timeout_s * 1e9)
        self.std_m = std_m
        self.good_fit_px = good_fit_px
        self.max_polished_starts = max_polished_starts
        self.model_points = top_face_model(self.length_m, self.width_m)
        self._prev: tuple[Vec3, float, int] | None = None
        if warm_up:
            self.warm_up()

    def warm_up(self) -> None:
        """Run the solver and the compiled region residual once on a synthetic view, so that
        numba's compilation (~15 s the first time on a machine, ~1 s from its disk cache)
        happens when the mission is built, not on the first narrow-camera frame."""
        model = CameraModel.from_lens("warm_up", focal_length_mm=12.0, mount=CameraMount(0, -30, 0))
        cam = Pose(np.array([[0.0, -0.5, 0.8660254037844387], [1.0, 0.0, 0.0],
                             [0.0, 0.8660254037844387, 0.5]]), np.array([-4.0, 0.0, -2.3]))
        R_ct, t_ct = target_pose_in_camera(cam, np.array([0.0, 0.0, -self.height_m]), 10.0)
        mbr = project_box_mbr(model, R_ct, t_ct, self.length_m, self.width_m, self.height_m)
        if mbr is not None:
            prev = self._prev
            self.solve_corners(mbr, model, cam)
            self._prev = prev

    def reset(self) -> None:
        self._prev = None

    # -- hypotheses ----------------------------------------------------------------------------
    def _shifts(self) -> tuple[int, ...]:
        return (0, 1, 2, 3)

    def candidates(
        self, corners_px: NDArray[np.float64], model: CameraModel, cam_ned: Pose,
    ) -> list[CornerSolution] | EstimationFailed:
        """Every (corner shift, solver candidate) hypothesis, scored, best first."""
        c = np.asarray(corners_px, dtype=np.float64).reshape(4, 2)
        if not np.isfinite(c).all():
            return EstimationFailed(f"{self.source}: detection corners are not finite")
        nrm = model.normalize(c)
        if not np.isfinite(nrm).all():
            return EstimationFailed(f"{self.source}: corners cannot be undistorted")
        prev = self._prev
        out: list[CornerSolution] = []
        reasons: list[str] = []
        for shift in self._shifts():
            obj = np.roll(self.model_points, shift, axis=0)  # image corner k <-> model k - shift
            est = self.solver(obj, nrm)
            if isinstance(est, EstimationFailed):
                reasons.append(str(est))
                continue
            poses = est.candidates or ((est.R, est.t_m),)
            for R, t in poses:
                Xc = obj @ R.T + t
                if not (Xc[:, 2] > 0).all():
                    continue
                # The top face must face the camera: its outward normal is the target's -z.
                normal_c = -R[:, 2]
                if float(normal_c @ t) >= 0:
                    continue
                px = model.project(Xc)
                err = float(np.linalg.norm(px - c, axis=1).mean())
                if not math.isfinite(err):
                    continue
                # obj holds true target-frame coordinates, so (R, t) is the target's pose.
                R_ct = R
                p, yaw, tilt = target_ned_from_camera(cam_ned, R_ct, t)
                score = err + self.tilt_weight_px_per_deg * max(0.0, tilt - self.tilt_free_deg)
                if prev is not None:
                    score += self.previous_pose_weight_px_per_m * float(np.linalg.norm(p - prev[0]))
                    score += self.yaw_weight_px_per_deg * abs(wrap_deg(yaw - prev[1]))
                else:
                    score += self.yaw_weight_px_per_deg * (0.0 if -90.0 <= yaw < 90.0 else 1.0)
                out.append(CornerSolution(shift, R_ct, t, p, yaw, tilt, err, score))
        if not out:
            why = "; ".join(sorted(set(reasons))) or "no hypothesis in front of the camera facing it"
            return EstimationFailed(f"{self.source}: no valid pose ({why})")
        out.sort(key=lambda s: s.score)
        return out

    def solve_corners(
        self, corners_px: NDArray[np.float64], model: CameraModel, cam_ned: Pose,
    ) -> CornerSolution | EstimationFailed:
        """The chosen hypothesis, MBR-corrected if configured."""
        cands = self.candidates(corners_px, model, cam_ned)
        c = np.asarray(corners_px, dtype=np.float64)
        mode = self.mbr_correction
        if mode == "none" or not np.isfinite(c).all():
            return cands if isinstance(cands, EstimationFailed) else cands[0]
        # Region models: the whole box's silhouette ("box_fit"), or also only its top face
        # ("auto": whichever explains the detected MBR better).
        heights = [self.height_m] if mode == "box_fit" else [self.height_m, 0.0]
        heights = list(dict.fromkeys(heights))
        start = None if isinstance(cands, EstimationFailed) else cands[0]
        if (mode == "auto" and start is not None and start.error_px < self.good_fit_px
                and start.tilt_deg <= self.tilt_free_deg):
            return start  # a flat top face explains the corners: they are the top face's
        fits: list[CornerSolution] = []
        for h in heights:
            f = self._box_fit(start, c, model, cam_ned, region_height_m=h)
            if f is not None:
                fits.append(f)
                if f.error_px < self.good_fit_px:
                    break  # explained to within the segmentation noise: no need for the next model
        if not fits:  # no region model fitted: the PnP choice, or why there is none
            return cands if isinstance(cands, EstimationFailed) else cands[0]
        best_fit = min(fits, key=lambda f: f.error_px)
        if (start is not None and start.error_px <= best_fit.error_px
                and start.tilt_deg <= self.tilt_free_deg):
            return start  # the corners are the top face itself (flat, fitted better): keep PnP
        return best_fit

    def _box_fit(
        self, start: CornerSolution | None, corners_px: NDArray[np.float64], model: CameraModel,
        cam_ned: Pose, *, region_height_m: float,
    ) -> CornerSolution | None:
        """Fit position + yaw (face horizontal) so that the MBR of the projected box of height
        ``region_height_m`` below the top face (0: the top face alone) matches the MBR."""
        from scipy.optimize import least_squares

        observed = order_corners(corners_px)
        corners_t = box_corners(self.length_m, self.width_m, region_height_m)
        R_cn = np.ascontiguousarray(cam_ned.R.T)
        cam_t = np.ascontiguousarray(cam_ned.t, dtype=np.float64)
        residual = _region_residual(model, corners_t, R_cn, cam_t, observed)
        jac = residual.jac if isinstance(residual, _CompiledRegionResidual) else None

        # Starts: the PnP pose, and the ray through the MBR centre meeting the plane of the
        # region's mid-height (ground assumed at d = 0, top at -height_m), then moved up to the
        # top face, with yaws every 15 deg (the box is symmetric under 180 deg); they are
        # polished best-first until one fits to ~good_fit_px (at most max_polished_starts).
        starts = [] if start is None else [np.array([*start.position_ned, start.yaw_deg])]
        ray = cam_ned.R @ model.rays_optical(observed.mean(axis=0))[0]
        if ray[2] > 1e-6:
            plane_down = -self.height_m + 0.5 * region_height_m
            s = (plane_down - cam_ned.t[2]) / ray[2]
            if s > 0:
                p0 = cam_ned.t + s * ray
                p0[2] = -self.height_m
                starts += [np.array([*p0, y]) for y in range(-90, 90, 15)]
        if not starts:
            return None
        good_cost = 0.5 * 8 * self.good_fit_px ** 2 / 2  # least_squares' cost at ~good_fit_px

        def polish(x0: NDArray[np.float64], nfev: int) -> _LMResult | None:
            if jac is not None:
                return _lm_fit(residual, jac, x0, nfev, xtol=1e-7, ftol=1e-6)
            try:
                sol = least_squares(residual, x0, jac="2-point", method="lm", diff_step=1e-6,
                                    xtol=1e-7, ftol=1e-6, max_nfev=nfev)
            except (ValueError, np.linalg.LinAlgError):
                return None
            if not np.isfinite(sol.x).all():
                return None
            return _LMResult(sol.x, sol.fun, sol.cost)

        # Stage 1: a couple of LM iterations from every start (the initial residual is a poor
        # guide: a start 5 deg off in yaw can look worse than a wrong branch); stage 2: polish
        # the best ones until one fits to ~good_fit_px.
        # The PnP start goes first: when a few iterations from it already fit to ~good_fit_px
        # the other starts are not tried (~0.2 ms each, 12 of them).
        coarse = []
        for k, x in enumerate(starts):
            sol = polish(x, 10)
            if sol is None:
                continue
            coarse.append(sol)
            if k == 0 and start is not None and sol.cost < good_cost:
                break
        coarse.sort(key=lambda sol: sol.cost)
        best_sol = None
        for c0 in coarse[: self.max_polished_starts]:
            sol = c0 if c0.cost < good_cost else polish(c0.x, 40)
            if sol is not None and (best_sol is None or sol.cost < best_sol.cost):
                best_sol = sol
            if best_sol is not None and best_sol.cost < good_cost:
                break
        if best_sol is None:
            return None
        # Escape a narrow local minimum (the MBR is piecewise smooth in the pose): restart from
        # the best fit with the yaw nudged (once; bounded cost when nothing fits, e.g. occlusion).
        for _ in range(1):
            if best_sol.cost < good_cost:
                break
            improved = False
            for dyaw in (3.0, -3.0, 6.0, -6.0):
                sol = polish(best_sol.x + (0.0, 0.0, 0.0, dyaw), 40)
                if sol is not None and sol.cost < best_sol.cost * 0.999:
                    best_sol, improved = sol, True
            if not improved:
                break
        sol = best_sol
        R_ct, t_ct = target_pose_in_camera(cam_ned, sol.x[:3], sol.x[3])
        err = float(np.linalg.norm(sol.fun.reshape(4, 2), axis=1).mean())
        shift, score = (start.shift, start.score) if start is not None else (0, err)
        return CornerSolution(shift, R_ct, t_ct, sol.x[:3].copy(), wrap_deg(float(sol.x[3])),
                              0.0, err, score)

    @property
    def yaw_period_deg(self) -> float:
        """Symmetry of the box about its vertical axis: 90 deg for a square top, else 180."""
        return 90.0 if abs(self.length_m - self.width_m) <= 1e-9 * self.length_m else 180.0

    def _disambiguate_yaw(self, sol: CornerSolution, previous_yaw_deg: float | None) -> CornerSolution:
        """Among the yaws the box's symmetry cannot tell apart (yaw + k * period), take the one
        nearest the previous yaw, else the one in [-period/2, period/2)."""
        period = self.yaw_period_deg
        if previous_yaw_deg is None:
            target = 0.0
        else:
            target = previous_yaw_deg
        k = round(wrap_deg(target - sol.yaw_deg) / period)
        if k == 0:
            return sol
        yaw = wrap_deg(sol.yaw_deg + k * period)
        R_ct = sol.R_ct @ rot_z(math.radians(k * period))
        return CornerSolution(sol.shift, R_ct, sol.t_ct, sol.position_ned, yaw, sol.tilt_deg,
                              sol.error_px, sol.score)

    # -- the estimator interface ---------------------------------------------------------------
    def estimate(self, detection: Detection, view: CameraView) -> TargetEstimate | EstimationFailed:
        cam_ned = view.camera_pose_ned
        best = self.solve_corners(detection.corners_px, view.model, cam_ned)
        if isinstance(best, EstimationFailed):
            return best
        if best.error_px > self.max_reprojection_error_px:
            return EstimationFailed(
                f"{self.source}: corner reprojection error {best.error_px:.1f} px exceeds "
                f"max_reprojection_error_px={self.max_reprojection_error_px:g}")
        ts = int(view.timestamp_ns)
        prev = self._prev
        if prev is not None and ts - prev[2] > self.previous_pose_timeout_ns:
            prev = None
        best = self._disambiguate_yaw(best, None if prev is None else prev[1])
        self._prev = (best.position_ned.copy(), best.yaw_deg, ts)
        rng = float(np.linalg.norm(best.t_ct))
        pose = PoseEstimate(R=best.R_ct, t_m=best.t_ct, reprojection_error=best.error_px)
        p_ned, p_cam = best.position_ned, best.t_ct
        return TargetEstimate(
            position_ned_m=(float(p_ned[0]), float(p_ned[1]), float(p_ned[2])),
            position_cam_m=(float(p_cam[0]), float(p_cam[1]), float(p_cam[2])),
            timestamp_ns=ts, camera_id=view.model.camera_id or detection.camera_id,
            source=self.source, full_3d=True, yaw_deg=best.yaw_deg,
            std_m=self.std_m * max(rng, 1.0), pose=pose)


_BOX_KERNEL: list[tuple[Any, Any] | None] = []


def _box_kernel() -> tuple[Any, Any] | None:
    """(region_residual, region_jacobian) compiled, or None without numba."""
    if not _BOX_KERNEL:
        try:
            from eaglemission.estimators._box_kernel import region_jacobian, region_residual
            kern: tuple[Any, Any] | None = (region_residual, region_jacobian)
        except ImportError:  # pragma: no cover - numba is a dependency
            kern = None
        _BOX_KERNEL.append(kern)
    return _BOX_KERNEL[0]


@dataclass(frozen=True)
class _LMResult:
    """The part of scipy's ``OptimizeResult`` the box fit reads."""

    x: NDArray[np.float64]
    fun: NDArray[np.float64]
    cost: float


def _lm_fit(fun: Callable[[NDArray[np.float64]], NDArray[np.float64]],
            jac: Callable[[NDArray[np.float64]], NDArray[np.float64]], x0: NDArray[np.float64],
            max_nfev: int, *, xtol: float, ftol: float, gtol: float = 1e-8) -> _LMResult | None:
    """Levenberg-Marquardt with an analytic Jacobian: the same MINPACK ``lmder`` call (same
    tolerances, ``factor=100``, scaling from the Jacobian) as
    ``least_squares(method="lm", jac=jac)`` in scipy >= 1.16, through ``scipy.optimize.leastsq``
    (~1/3 of the per-call overhead: no VectorFunction wrappers). Same iterates and result; None
    where ``least_squares`` raises (residuals not finite at ``x0``) or the result is not finite.
    """
    from scipy.optimize import leastsq

    x0 = np.atleast_1d(np.asarray(x0, dtype=np.float64)).copy()
    f0 = np.asarray(fun(x0), dtype=np.float64)
    if not np.isfinite(f0).all():
        return None
    try:
        out = leastsq(fun, x0, Dfun=jac, full_output=True, col_deriv=False, ftol=ftol,
                      xtol=xtol, gtol=gtol, maxfev=max_nfev, factor=100.0, diag=None)
    except (ValueError, np.linalg.LinAlgError):
        return None
    x, info = np.asarray(out[0], dtype=np.float64), out[2]
    if not np.isfinite(x).all():
        return None
    f = np.asarray(info["fvec"], dtype=np.float64)
    return _LMResult(x, f, float(0.5 * np.dot(f, f)))


class _CompiledRegionResidual:
    """The compiled region residual (called with x) and its analytic Jacobian (``.jac(x)``)."""

    __slots__ = ("_fun", "_jac", "_corners_t", "_R_cn", "_cam_t", "_K", "_dist", "_obs")

    def __init__(self, kern: tuple[Any, Any], corners_t: NDArray[np.float64],
                 R_cn: NDArray[np.float64], cam_t: NDArray[np.float64], K: NDArray[np.float64],
                 dist: NDArray[np.float64], obs: NDArray[np.float64]) -> None:
        self._fun, self._jac = kern
        self._corners_t, self._R_cn, self._cam_t = corners_t, R_cn, cam_t
        self._K, self._dist, self._obs = K, dist, obs

    def __call__(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        r: NDArray[np.float64] = self._fun(np.asarray(x, dtype=np.float64), self._corners_t,
                                           self._R_cn, self._cam_t, self._K, self._dist, self._obs)
        return r

    def jac(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        J: NDArray[np.float64] = self._jac(np.asarray(x, dtype=np.float64), self._corners_t,
                                           self._R_cn, self._cam_t, self._K, self._dist, self._obs)
        return J


def _region_residual(
    model: CameraModel, corners_t: NDArray[np.float64], R_cn: NDArray[np.float64],
    cam_t: NDArray[np.float64], observed: NDArray[np.float64], *, backend: str = "numba",
) -> Callable[[NDArray[np.float64]], NDArray[np.float64]]:
    """Residual of the region-model fit: (north, east, down, yaw_deg) -> 8 corner residuals (px)
    between the minimum-area rectangle of the projected region and the observed MBR, matched
    up to a cyclic relabelling (the "top-left" corner of a rectangle standing on a vertex flips
    between neighbours, which would make the residual jump). Compiled (numba) for 0, 4, 5 or 8
    distortion coefficients, numpy otherwise."""
    dist = (np.asarray(model.distortion, dtype=np.float64)
            if model.distortion and any(model.distortion) else np.zeros(0))
    kern = _box_kernel() if backend == "numba" and dist.size in (0, 4, 5, 8) else None
    if kern is not None:
        return _CompiledRegionResidual(kern, corners_t, R_cn, cam_t,
                                       np.ascontiguousarray(model.K, dtype=np.float64), dist,
                                       np.ascontiguousarray(observed, dtype=np.float64))

    def residual(x: NDArray[np.float64]) -> NDArray[np.float64]:
        c, s_ = math.cos(math.radians(x[3])), math.sin(math.radians(x[3]))
        R_ct = R_cn @ np.array([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]])
        pts = corners_t @ R_ct.T + R_cn @ (np.asarray(x[:3]) - cam_t)
        if not (pts[:, 2] > 1e-6).all():
            return np.full(8, 1e3)
        pred = min_area_rect_corners(model.project(pts))
        best = None
        for k in range(4):
            r = np.roll(pred, k, axis=0) - observed
            if best is None or float(np.einsum("ij,ij->", r, r)) < float(np.einsum("ij,ij->", best, best)):
                best = r
        assert best is not None
        return best.reshape(-1)

    return residual
