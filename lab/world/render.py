"""The synthetic world: a textured ground plane, sky, the target box and distractors, rendered
for any camera on the vehicle, with ground truth kept in a side channel.

Geometry (docs/conventions.md): local NED with the ground plane at ``d = 0``; the target is a
box whose top face is at ``d = -height_m``, centred at (``target_north_m``, ``target_east_m``)
and yawed by ``target_yaw_deg`` (its x axis, along ``length_m``, points at that heading).

Rendering (docs/simulation.md, "Synthetic world"):

1. ground: plane-induced homography from texture texels to pixels, one ``cv2.warpPerspective``
   per horizontal band of rows; each band reads the mip level whose texel matches the band's
   ground footprint (base colour texture at 5 cm and coarser; plus a periodic fine detail
   modulation down to 2.5 mm for close-range bands) -- sharp at 0.5 m with the 12 mm lens,
   free of aliasing at 15 m with the 2.8 mm lens;
2. sky: pixels whose ray points at or above the horizon;
3. boxes, discs and stripes: their visible faces projected and filled (Lambert shading with a
   seed-chosen sun), painted far to near; then a simulated arm's gripper under the body, when
   the flight has one (its tool point in body FRD);
4. motion blur (``motion_blur``: along the image motion during the exposure), lighting gain
   x white balance, lens distortion (if the model has any: the pinhole render is remapped),
   additive Gaussian noise from a pre-drawn bank, Bayer mosaic + demosaic (``bayer_pattern``),
   JPEG round trip (``jpeg_quality``): :mod:`.imaging`.

Realism knobs (``SyntheticWorldConfig``) make the rendering camera differ from the nominal
:class:`CameraModel` the estimators use: ``mount_error_deg`` (a fixed random rotation, per
camera, of at most that angle), ``focal_error_fraction`` (true focal = nominal x (1 + e),
``|e| <=`` the fraction, per camera). ``camera_time_offset_s`` is applied by
:class:`~eaglemission.lab.cameras.synthetic.SyntheticCamera`.

Every rendered image is a pure function of (seed, configs, camera model, pose, time; with
``motion_blur``, the exposure's start pose too): the same
inputs give the same bytes.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import zlib
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from eaglemission.lab.cameras.imaging import (
    apply_colour_gains,
    bayer_round_trip,
    jpeg_round_trip,
    motion_blur,
    optical_axis_motion_px,
)
from eaglemission.lab.world.arm_drawing import draw_arm
from eaglemission.lab.world.ground import (
    BGRA_LEVEL_BUDGET_BYTES,
    SKY_HORIZON_BGR,
    SKY_ZENITH_BGR,
    GroundRenderer,
)
from eaglemission.lab.world.objects import (
    EPOCH_NS,
    NEAR_PLANE_M,
    SceneObject,
    box_faces,
    clip_polygon,
    clip_to_rect,
    distractor_object,
    polygon_area,
    random_rotation,
    seed_rng,
)
from eaglemission.lab.world.synthetic import SyntheticWorldConfig
from eaglemission.lab.world.textures import GroundTextures, ground_textures
from numpy.typing import NDArray

from eaglemission.config import TargetConfig
from eaglemission.geometry import (
    R_FRD_FROM_OPTICAL,
    CameraModel,
    CameraMount,
    Pose,
    R_to_euler,
    quat_to_R,
)
from eaglemission.geometry.tool_marker import ToolMarker
from eaglemission.types import XYZ, Points2

__all__ = ["BGRA_LEVEL_BUDGET_BYTES", "DEFAULT_TARGET_BGR", "SKY_HORIZON_BGR", "SKY_ZENITH_BGR",
           "GroundTruth", "SyntheticWorld", "box_faces", "clip_polygon", "clip_to_rect",
           "polygon_area", "random_rotation"]

DEFAULT_TARGET_BGR = (30, 40, 210)
SHADOW_FACTOR = 0.55  # ground brightness in a box's cast shadow (ambient light only)


# ---------------------------------------------------------------------------------------------
# Ground truth
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GroundTruth:
    """What the renderer knows about one image. Never inside a Frame: tests and the evaluator
    read it from ``SyntheticWorld.truth(camera_id, seq)``.

    Attributes
    ----------
    target_visible : some of the target's projection (> 0.5 px^2) lies inside the image
    target_polygon_px : (n, 2) outline of the target's projection clipped to the image
        (occlusion by distractors is not taken into account)
    top_corners_px : (4, 2) top-face corners in target-model order (+L/2,-W/2), (+L/2,+W/2),
        (-L/2,+W/2), (-L/2,-W/2), projected with the TRUE camera (NaN when behind it)
    target_pose_cam : target frame -> TRUE camera optical frame, ``X_c = R @ X_o + t``
    target_position_ned_m : centre of the target's top face in NED
    target_yaw_deg : target heading
    top_face_visible : the top face faces the camera and all 4 corners are inside the image
    timestamp_ns : the frame's stamp (mid-exposure as reported)
    render_time_ns : the time of the pose and world state actually rendered
        (``timestamp_ns - camera_time_offset_s``)
    camera_position_ned_m, R_ned_optical : the TRUE camera pose at ``render_time_ns``
    true_model : the TRUE camera (intrinsics with focal error, mount with mount error)
    motion_blur_px : (du, dv) in pixels, the image motion during the exposure the frame is
        smeared along (0, 0 without ``motion_blur``)
    """

    target_visible: bool
    target_polygon_px: Points2
    top_corners_px: Points2
    target_pose_cam: Pose
    target_position_ned_m: XYZ
    target_yaw_deg: float
    top_face_visible: bool = False
    timestamp_ns: int = 0
    render_time_ns: int = 0
    camera_position_ned_m: XYZ = (0.0, 0.0, 0.0)
    R_ned_optical: NDArray[np.float64] = field(default_factory=lambda: np.eye(3))
    true_model: CameraModel | None = None
    motion_blur_px: tuple[float, float] = (0.0, 0.0)
    """(du, dv) image motion the frame is smeared along (``motion_blur``; 0 without)"""


# ---------------------------------------------------------------------------------------------
# Per-camera render context (cached)
# ---------------------------------------------------------------------------------------------
@dataclass
class _CameraCtx:
    K_true: NDArray[np.float64]
    R_body_optical_true: NDArray[np.float64]
    true_model: CameraModel
    noise_pos: NDArray[np.uint8] | None
    noise_neg: NDArray[np.uint8] | None
    undistort_maps: tuple[NDArray[np.float32], NDArray[np.float32]] | None
    noise_pad: int = 48


class SyntheticWorld:
    """The simulated scene and renderer (one per simulation; shared by both cameras).

    Parameters
    ----------
    simulation : target placement, ground texture, distractors, lighting, noise, realism knobs
    target : the target box (size and colour)
    seed : seed of everything random (textures, sun, noise, realism knobs); defaults to
        ``simulation.seed``
    extent_m : side of the textured square around home; beyond it the ground is its mean
        colour. Defaults to enough for the target, the distractors and a 100 m geofence.
    base_texel_m : texel of the unique base texture (its memory is ``3 (extent/texel)^2``
        bytes, ~70 MB for 240 m at 5 cm, plus mips and ~80 MB of detail tiles)
    truth_history : ground-truth records kept per camera
    """

    def __init__(self, simulation: SyntheticWorldConfig | None, target: TargetConfig, *,
                 seed: int | None = None, extent_m: float | None = None,
                 base_texel_m: float = 0.05, truth_history: int = 2000) -> None:
        self.simulation = simulation or SyntheticWorldConfig()
        self.target = target
        self.seed = int(self.simulation.seed if seed is None else seed)
        sim = self.simulation
        if extent_m is None:
            reach = [100.0, math.hypot(sim.target_north_m, sim.target_east_m) + 30.0]
            reach += [math.hypot(d.north_m, d.east_m) + 30.0 for d in sim.distractors]
            extent_m = 2.0 * max(reach)
        if extent_m > 1000.0:
            raise ValueError(
                f"extent_m: {extent_m:.0f} m is too large for a {base_texel_m} m texel texture "
                f"(memory); place the target and distractors within 500 m of home")
        self.extent_m = float(extent_m)
        self.textures: GroundTextures = self._ground_textures(float(extent_m), base_texel_m)
        rng = seed_rng(self.seed, "sun")
        az = math.radians(rng.uniform(-180.0, 180.0))
        el = math.radians(rng.uniform(35.0, 65.0))
        # Unit vector from the ground towards the sun, NED.
        self.sun_ned = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az),
                                 -math.sin(el)])
        colour = target.color_bgr if target.color_bgr is not None else DEFAULT_TARGET_BGR
        self.target_colour_bgr: tuple[int, int, int] = (int(colour[0]), int(colour[1]),
                                                         int(colour[2]))
        self._target = SceneObject("target", tuple(box_faces(target.length_m, target.width_m,
                                                         target.height_m)),
                               self.target_colour_bgr, sim.target_north_m, sim.target_east_m,
                               -target.height_m, sim.target_yaw_deg)
        self._objects = [distractor_object(i, d, self.seed)
                         for i, d in enumerate(sim.distractors)]
        self._ctx: dict[tuple[object, ...], _CameraCtx] = {}
        self.ground = GroundRenderer(self.textures)
        self._lock = threading.Lock()
        self._truth: dict[str, OrderedDict[int, GroundTruth]] = {}
        self._truth_history = int(truth_history)

    def _ground_textures(self, extent_m: float, base_texel_m: float) -> GroundTextures:
        gi = self.simulation.ground_image
        if gi is None:
            return ground_textures(self.simulation.ground_texture, self.seed, extent_m,
                                   base_texel_m)
        from eaglemission.lab.world.photo_ground import photo_ground_textures

        assert gi.m_per_px is not None  # filled from the sidecar by the config
        return photo_ground_textures(gi.path, float(gi.m_per_px), self.seed, extent_m,
                                     (float(gi.offset_ne_m[0]), float(gi.offset_ne_m[1])),
                                     gi.detail)

    # -- target ---------------------------------------------------------------------------------
    @property
    def target_object(self) -> SceneObject:
        """The target box as a scene object: its faces in the target frame, its placement."""
        return self._target

    @property
    def target_position_ned_m(self) -> XYZ:
        s = self.simulation
        return (float(s.target_north_m), float(s.target_east_m), -float(self.target.height_m))

    def target_pose_ned(self) -> Pose:
        """Target frame -> NED."""
        R, t = self._target.pose_ned(EPOCH_NS)
        return Pose(R, t)

    def target_top_corners_ned(self) -> NDArray[np.float64]:
        """(4, 3) top-face corners in NED, target-model order."""
        return self.target_pose_ned().apply(self._target.faces[0][0])

    def shade(self, normal_ned: NDArray[np.float64]) -> float:
        """Lambert factor of a face: ambient 0.45 + diffuse 0.55 cos(sun angle)."""
        return 0.45 + 0.55 * max(0.0, float(normal_ned @ self.sun_ned))

    def face_colour(self, colour_bgr: Sequence[int], normal_ned: NDArray[np.float64]
                    ) -> tuple[int, int, int]:
        """The colour a face is filled with before the lighting gain and noise."""
        k = self.shade(normal_ned)
        c = [int(min(255, round(v * k))) for v in colour_bgr]
        return (c[0], c[1], c[2])

    @property
    def target_top_colour_bgr(self) -> tuple[int, int, int]:
        return self.face_colour(self.target_colour_bgr, np.array([0.0, 0.0, -1.0]))

    # -- the true camera ----------------------------------------------------------------------
    def _camera_ctx(self, model: CameraModel) -> _CameraCtx:
        key = (model.camera_id, model.width_px, model.height_px, model.K.tobytes(),
               tuple(model.distortion), model.mount)
        with self._lock:
            ctx = self._ctx.get(key)
        if ctx is not None:
            return ctx
        sim = self.simulation
        rng = seed_rng(self.seed, "camera", model.camera_id)
        R_err = random_rotation(sim.mount_error_deg, rng)
        e = rng.uniform(-sim.focal_error_fraction, sim.focal_error_fraction) \
            if sim.focal_error_fraction > 0 else 0.0
        K_true = model.K.copy()
        K_true[0, 0] *= 1.0 + e
        K_true[1, 1] *= 1.0 + e
        R_bo = R_err @ model.mount.R_body_optical
        roll, pitch, yaw = R_to_euler(R_bo @ R_FRD_FROM_OPTICAL.T)
        true_model = model.with_(K=K_true, mount=CameraMount(roll, pitch, yaw,
                                                             model.mount.lever_arm_m),
                                 focal_length_mm=model.focal_length_mm * (1.0 + e))
        noise_pos = noise_neg = None
        pad = 48
        if sim.noise_sigma > 0:
            nrng = seed_rng(self.seed, "noise", model.camera_id)
            n = nrng.standard_normal((model.height_px + pad, model.width_px + pad, 3))
            n = np.rint(n * sim.noise_sigma).astype(np.int16)
            noise_pos = np.clip(n, 0, 255).astype(np.uint8)
            noise_neg = np.clip(-n, 0, 255).astype(np.uint8)
        maps = None
        if model.distortion and any(model.distortion):
            # For each distorted output pixel, where it falls in the pinhole render.
            m1, m2 = cv2.initUndistortRectifyMap(K_true, model.dist_array, None, K_true,
                                                 (model.width_px, model.height_px),
                                                 cv2.CV_32FC1)
            maps = (np.asarray(m1, dtype=np.float32), np.asarray(m2, dtype=np.float32))
        ctx = _CameraCtx(K_true, R_bo, true_model, noise_pos, noise_neg, maps, pad)
        with self._lock:
            self._ctx[key] = ctx
        return ctx

    def true_camera(self, model: CameraModel) -> CameraModel:
        """The camera that actually renders ``model``'s images (focal and mount errors)."""
        return self._camera_ctx(model).true_model

    # -- ground truth side channel --------------------------------------------------------
    def record_truth(self, camera_id: str, seq: int, truth: GroundTruth) -> None:
        with self._lock:
            d = self._truth.setdefault(camera_id, OrderedDict())
            d[seq] = truth
            while len(d) > self._truth_history:
                d.popitem(last=False)

    def truth(self, camera_id: str, seq: int) -> GroundTruth:
        """Ground truth of frame ``seq`` of ``camera_id`` (kept for the last
        ``truth_history`` frames). Only tests and the evaluator read this."""
        with self._lock:
            d = self._truth.get(camera_id)
            if d is None or seq not in d:
                have = f"{min(d)}..{max(d)}" if d else "none"
                raise KeyError(f"no ground truth for camera {camera_id!r} frame {seq} "
                               f"(kept: {have}); it was never rendered or is older than "
                               f"truth_history={self._truth_history}")
            return d[seq]

    # -- rendering ---------------------------------------------------------------------------
    def render(self, model: CameraModel, position_ned_m: Sequence[float],
               attitude_q: Sequence[float], timestamp_ns: int, *,
               exposure_start_pose: tuple[Sequence[float], Sequence[float]] | None = None,
               tool_body_m: Sequence[float] | None = None,
               tool_marker: ToolMarker | None = None
               ) -> tuple[NDArray[np.uint8], GroundTruth]:
        """Render what ``model`` sees from a vehicle at ``position_ned_m`` with attitude
        ``attitude_q`` (body FRD -> NED), with the world as it is at ``timestamp_ns``.

        ``exposure_start_pose``: the vehicle's (position, attitude) half an exposure earlier
        (the start of the exposure); with the world's ``motion_blur`` the image is smeared
        along twice the image motion between the two poses of the scene point on the
        principal-point pixel, centred on the mid-exposure image (constant velocity and
        angular rate over the exposure; :mod:`.imaging`).

        ``tool_body_m``: an arm's tool point in body FRD (a simulated manipulator): the arm is
        drawn under the body: a small grey gripper block on the end of a dark Z slide;
        ``tool_marker``: the ArUco marker on its white plate on the gripper.

        Returns the BGR image (H, W, 3) uint8 and its :class:`GroundTruth` (``timestamp_ns``
        and ``render_time_ns`` both set to ``timestamp_ns``).
        """
        ctx = self._camera_ctx(model)
        C, R_on = self._camera_pose(model, ctx, position_ned_m, attitude_q)
        R_no = R_on.T  # optical -> NED
        W, H = model.width_px, model.height_px
        img = np.empty((H, W, 3), np.uint8)
        self._render_ground(img, ctx.K_true, R_on, C)
        self._render_sky(img, ctx.K_true, R_no)
        self._render_objects(img, ctx.K_true, R_on, C, int(timestamp_ns))
        if tool_body_m is not None:
            draw_arm(self, img, ctx.K_true, R_on, C, position_ned_m, attitude_q, tool_body_m,
                     tool_marker)
        sim = self.simulation
        blur = (0.0, 0.0)
        if sim.motion_blur and exposure_start_pose is not None:
            C0, R_on0 = self._camera_pose(model, ctx, *exposure_start_pose)
            du, dv = optical_axis_motion_px(ctx.K_true, R_on, C, R_on0, C0)
            blur = (2.0 * du, 2.0 * dv)  # half an exposure -> the whole exposure
            img = motion_blur(img, *blur)
        gain = sim.light_gain
        wb = sim.white_balance_gains_bgr
        if wb != (1.0, 1.0, 1.0):
            apply_colour_gains(img, [gain * g for g in wb])
        elif gain != 1.0:
            cv2.convertScaleAbs(img, dst=img, alpha=gain)
        if ctx.undistort_maps is not None:
            img = np.asarray(cv2.remap(img, ctx.undistort_maps[0], ctx.undistort_maps[1],
                                       cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE),
                             dtype=np.uint8)
        if ctx.noise_pos is not None and ctx.noise_neg is not None:
            h = zlib.crc32(f"{model.camera_id}/{int(timestamp_ns)}".encode()) ^ self.seed
            oy, ox = (h % ctx.noise_pad), ((h // ctx.noise_pad) % ctx.noise_pad)
            cv2.add(img, ctx.noise_pos[oy:oy + H, ox:ox + W], dst=img)
            cv2.subtract(img, ctx.noise_neg[oy:oy + H, ox:ox + W], dst=img)
        if sim.bayer_pattern is not None:
            img = bayer_round_trip(img, sim.bayer_pattern)
        if sim.jpeg_quality is not None:
            img = jpeg_round_trip(img, sim.jpeg_quality)
        truth = self._ground_truth(ctx, R_on, C, int(timestamp_ns))
        return img, dataclasses.replace(truth, motion_blur_px=blur) if blur != (0.0, 0.0) \
            else truth

    def _camera_pose(self, model: CameraModel, ctx: _CameraCtx, position_ned_m: Sequence[float],
                     attitude_q: Sequence[float]
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The true optical centre (NED) and NED -> optical rotation of ``model`` on a vehicle
        at ``position_ned_m`` with ``attitude_q``."""
        R_nb = quat_to_R(attitude_q)
        p = np.asarray(position_ned_m, dtype=np.float64)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ValueError(f"position_ned_m: must be 3 finite numbers, got {position_ned_m!r}")
        C = p + R_nb @ np.asarray(model.mount.lever_arm_m, dtype=np.float64)
        return C, (R_nb @ ctx.R_body_optical_true).T

    # ground and sky (:mod:`.world_ground`) ---------------------------------------------------
    def _render_ground(self, img: NDArray[np.uint8], K: NDArray[np.float64],
                       R_on: NDArray[np.float64], C: NDArray[np.float64]) -> None:
        self.ground.render_ground(img, K, R_on, C)

    def _render_sky(self, img: NDArray[np.uint8], K: NDArray[np.float64],
                    R_no: NDArray[np.float64]) -> None:
        self.ground.render_sky(img, K, R_no)

    def warm_up(self) -> None:
        """Build the 4-channel base levels now (~50 ms for a 200 m world) rather than inside
        the first frames of a timed flight."""
        self.ground.warm_up()

    # boxes, discs, stripes --------------------------------------------------------------
    def _render_objects(self, img: NDArray[np.uint8], K: NDArray[np.float64],
                        R_on: NDArray[np.float64], C: NDArray[np.float64], time_ns: int) -> None:
        H, W = img.shape[:2]
        items = []
        for obj in [*self._objects, self._target]:
            R, t = obj.pose_ned(time_ns)
            items.append((float(np.linalg.norm(t - C)), obj, R, t))
        items.sort(key=lambda it: -it[0])  # far to near (painter's algorithm)
        for _, obj, R, t in items:
            self._render_shadow(img, K, R_on, C, obj, R, t)
        for _, obj, R, t in items:
            for verts, nrm in obj.faces:
                v_ned = verts @ R.T + t
                n_ned = R @ nrm
                if float(n_ned @ (C - v_ned[0])) <= 0.0:
                    continue  # back face
                colour = self.face_colour(obj.colour_bgr, n_ned)
                self._fill_face(img, K, R_on, C, v_ned, colour, W, H)

    def shadow_polygon_ned(self, obj_faces: Sequence[tuple[NDArray[np.float64],
                                                           NDArray[np.float64]]],
                           R: NDArray[np.float64], t: NDArray[np.float64]
                           ) -> NDArray[np.float64] | None:
        """(n, 3) ground polygon (d = 0) of the shadow an object casts under the sun, or None
        for flat objects and a sun at the horizon."""
        if len(obj_faces) < 2 or self.sun_ned[2] > -0.05:
            return None
        verts = np.concatenate([v for v, _ in obj_faces]) @ R.T + t
        light = -self.sun_ned  # direction the light travels (d-component > 0)
        s = -verts[:, 2] / light[2]
        ground = verts[:, :2] + s[:, None] * light[:2]
        hull = cv2.convexHull(ground.astype(np.float32)).reshape(-1, 2).astype(np.float64)
        return np.column_stack((hull, np.full(len(hull), -1e-3)))

    def _render_shadow(self, img: NDArray[np.uint8], K: NDArray[np.float64],
                       R_on: NDArray[np.float64], C: NDArray[np.float64], obj: SceneObject,
                       R: NDArray[np.float64], t: NDArray[np.float64]) -> None:
        poly = self.shadow_polygon_ned(obj.faces, R, t)
        if poly is None:
            return
        H, W = img.shape[:2]
        v_cam = clip_polygon((poly - C) @ R_on.T, np.array([0.0, 0.0, 1.0]), NEAR_PLANE_M)
        if len(v_cam) < 3:
            return
        uv = v_cam @ K.T
        uv = clip_to_rect(uv[:, :2] / uv[:, 2:3], -0.5, -0.5, W - 0.5, H - 0.5)
        if polygon_area(uv) < 0.5:
            return
        x0, y0 = (max(0, int(math.floor(v))) for v in uv.min(axis=0))
        x1, y1 = (min(m, int(math.ceil(v)) + 1) for v, m in zip(uv.max(axis=0), (W, H)))
        if x1 <= x0 or y1 <= y0:
            return
        mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
        pts = np.round((uv - (x0, y0)) * 16).astype(np.int32)
        cv2.fillConvexPoly(mask, pts, 1, cv2.LINE_AA, 4)  # antialiased edge: a soft penumbra
        roi = img[y0:y1, x0:x1]
        dark = cv2.convertScaleAbs(roi, alpha=SHADOW_FACTOR)
        cv2.copyTo(dark, mask, roi)  # in place where mask != 0 (as np.copyto(where=...))

    @staticmethod
    def _fill_face(img: NDArray[np.uint8], K: NDArray[np.float64], R_on: NDArray[np.float64],
                   C: NDArray[np.float64], v_ned: NDArray[np.float64],
                   colour: tuple[int, int, int], W: int, H: int) -> None:
        v_cam = (v_ned - C) @ R_on.T
        v_cam = clip_polygon(v_cam, np.array([0.0, 0.0, 1.0]), NEAR_PLANE_M)
        if len(v_cam) < 3:
            return
        uv = (v_cam @ K.T)
        uv = uv[:, :2] / uv[:, 2:3]
        uv = clip_to_rect(uv, -2.0 * W, -2.0 * H, 3.0 * W, 3.0 * H)
        if len(uv) < 3:
            return
        cv2.fillConvexPoly(img, np.round(uv * 16).astype(np.int32), colour, cv2.LINE_8, 4)

    # ground truth --------------------------------------------------------------------------
    def _ground_truth(self, ctx: _CameraCtx, R_on: NDArray[np.float64], C: NDArray[np.float64],
                      time_ns: int) -> GroundTruth:
        model = ctx.true_model
        W, H = model.width_px, model.height_px
        R_nt, t_nt = self._target.pose_ned(time_ns)
        pose = Pose(R_on @ R_nt, R_on @ (t_nt - C))
        top = self._target.faces[0][0]
        top_cam = pose.apply(top)
        corners = model.project(top_cam)
        pts: list[NDArray[np.float64]] = []
        top_facing = False
        for k, (verts, nrm) in enumerate(self._target.faces):
            v_ned = verts @ R_nt.T + t_nt
            if float((R_nt @ nrm) @ (C - v_ned[0])) <= 0.0:
                continue
            if k == 0:
                top_facing = True
            vc = clip_polygon((v_ned - C) @ R_on.T, np.array([0.0, 0.0, 1.0]), NEAR_PLANE_M)
            if len(vc):
                pts.append(model.project(vc))
        polygon = np.zeros((0, 2))
        if pts:
            allp = np.concatenate(pts)
            allp = allp[np.isfinite(allp).all(axis=1)]
            if len(allp) >= 3:
                hull = cv2.convexHull(allp.astype(np.float32)).reshape(-1, 2).astype(np.float64)
                polygon = clip_to_rect(hull, -0.5, -0.5, W - 0.5, H - 0.5)
        visible = polygon_area(polygon) > 0.5
        top_visible = bool(top_facing and np.isfinite(corners).all()
                           and model.in_image(corners).all())
        R_no = R_on.T
        return GroundTruth(
            target_visible=bool(visible), target_polygon_px=polygon, top_corners_px=corners,
            target_pose_cam=pose,
            target_position_ned_m=(float(t_nt[0]), float(t_nt[1]), float(t_nt[2])),
            target_yaw_deg=float(self._target.yaw_deg), top_face_visible=top_visible,
            timestamp_ns=time_ns, render_time_ns=time_ns,
            camera_position_ned_m=(float(C[0]), float(C[1]), float(C[2])),
            R_ned_optical=R_no, true_model=model)
