"""The synthetic world: a textured ground plane, sky, the target box and distractors, rendered
for any camera on the vehicle, with ground truth kept in a side channel.

Geometry (docs/conventions.md): local NED with the ground plane at ``d = 0``; the target is a
box whose top face is at ``d = -height_m``, centred at (``target_north_m``, ``target_east_m``)
and yawed by ``target_yaw_deg`` (its x axis, along ``length_m``, points at that heading).

Rendering (docs/cameras.md, "Synthetic world"):

1. ground: plane-induced homography from texture texels to pixels, one ``cv2.warpPerspective``
   per horizontal band of rows; each band reads the mip level whose texel matches the band's
   ground footprint (base colour texture at 5 cm and coarser; plus a periodic fine detail
   modulation down to 2.5 mm for close-range bands) -- sharp at 0.5 m with the 12 mm lens,
   free of aliasing at 15 m with the 2.8 mm lens;
2. sky: pixels whose ray points at or above the horizon;
3. boxes, discs and stripes: their visible faces projected and filled (Lambert shading with a
   seed-chosen sun), painted far to near;
4. lighting gain, lens distortion (if the model has any: the pinhole render is remapped),
   additive Gaussian noise from a pre-drawn bank.

Realism knobs (``SimulationConfig``) make the rendering camera differ from the nominal
:class:`CameraModel` the estimators use: ``mount_error_deg`` (a fixed random rotation, per
camera, of at most that angle), ``focal_error_fraction`` (true focal = nominal x (1 + e),
``|e| <=`` the fraction, per camera). ``camera_time_offset_s`` is applied by
:class:`~eaglemission.drivers.cameras.synthetic.SyntheticCamera`.

Every rendered image is a pure function of (seed, configs, camera model, pose, time): the same
inputs give the same bytes.
"""

from __future__ import annotations

import math
import threading
import zlib
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from eaglemission.drivers.cameras.textures import GroundTextures, ground_textures
from numpy.typing import NDArray

from eaglemission.config import DistractorConfig, SimulationConfig, TargetConfig
from eaglemission.geometry import (
    R_FRD_FROM_OPTICAL,
    CameraModel,
    CameraMount,
    Pose,
    R_to_euler,
    quat_to_R,
    rot_z,
)
from eaglemission.types import XYZ, Points2

DEFAULT_TARGET_BGR = (30, 40, 210)
SKY_ZENITH_BGR = (205, 150, 95)
SKY_HORIZON_BGR = (235, 215, 200)
NEAR_PLANE_M = 0.02
SHADOW_FACTOR = 0.55  # ground brightness in a box's cast shadow (ambient light only)
HAZE_VISIBILITY_M = 400.0  # aerial perspective: 1/e distance of the haze
HAZE_MAX = 0.9  # haze opacity at infinity (the horizon stays faintly visible)
HAZE_MIN_M = 30.0  # rows whose ground is nearer than this are left untouched
EPOCH_NS = 1_000_000_000  # VirtualTimeLoop starts at 1 s: moving distractors start there
# The ground is warped from 4-channel copies of the base texture levels (OpenCV's 4-channel
# bilinear warp is ~2x faster than its 3-channel one; same values per channel) for levels up to
# this size (level 0 of a 200 m world at 5 cm is 64 MB); larger levels use the 3-channel path.
BGRA_LEVEL_BUDGET_BYTES = 192 * 2**20


def _seed_rng(seed: int, *salt: str) -> np.random.RandomState:
    h = zlib.crc32("/".join(salt).encode()) ^ ((int(seed) * 2654435761) & 0xFFFFFFFF)
    return np.random.RandomState(h & 0xFFFFFFFF)


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


# ---------------------------------------------------------------------------------------------
# Small pure geometry helpers
# ---------------------------------------------------------------------------------------------
def clip_polygon(poly: NDArray[np.float64], normal: NDArray[np.float64], offset: float
                 ) -> NDArray[np.float64]:
    """Sutherland-Hodgman: keep the part of a polygon (n, k) where ``p @ normal >= offset``."""
    if len(poly) == 0:
        return poly
    d = poly @ normal - offset
    inside = d >= 0
    if inside.all():  # nothing to clip (most faces): the vertices as they are
        return np.array(poly, dtype=np.float64).reshape(-1, poly.shape[1])
    if not inside.any():
        return np.zeros((0, poly.shape[1]))
    out: list[NDArray[np.float64]] = []
    n = len(poly)
    for i in range(n):
        a, b = poly[i], poly[(i + 1) % n]
        da, db = d[i], d[(i + 1) % n]
        if da >= 0:
            out.append(a)
        if (da >= 0) != (db >= 0):
            s = da / (da - db)
            out.append(a + s * (b - a))
    return np.asarray(out, dtype=np.float64).reshape(-1, poly.shape[1])


def clip_to_rect(poly: NDArray[np.float64], x0: float, y0: float, x1: float, y1: float
                 ) -> NDArray[np.float64]:
    """Clip a 2-D polygon to the axis-aligned rectangle ``[x0, x1] x [y0, y1]``."""
    for nrm, off in (((1.0, 0.0), x0), ((-1.0, 0.0), -x1), ((0.0, 1.0), y0), ((0.0, -1.0), -y1)):
        poly = clip_polygon(poly, np.asarray(nrm), off)
        if len(poly) == 0:
            break
    return poly


def polygon_area(poly: NDArray[np.float64]) -> float:
    if len(poly) < 3:
        return 0.0
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def random_rotation(max_angle_deg: float, rng: np.random.RandomState) -> NDArray[np.float64]:
    """A rotation about a uniformly random axis by an angle uniform in [0, max_angle_deg]."""
    if max_angle_deg <= 0:
        return np.eye(3)
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    angle = math.radians(rng.uniform(0.0, max_angle_deg))
    R, _ = cv2.Rodrigues(axis * angle)
    return np.asarray(R, dtype=np.float64)


def box_faces(length_m: float, width_m: float, height_m: float
              ) -> list[tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """Faces of a box in its own frame (x along length, y along width, z down, top face at
    z = 0, bottom at z = height): list of (4x3 vertices, outward normal). Top face first,
    its vertices in target-model order."""
    L, W, h = length_m / 2.0, width_m / 2.0, height_m
    top = np.array([[L, -W, 0], [L, W, 0], [-L, W, 0], [-L, -W, 0]], dtype=np.float64)
    faces = [(top, np.array([0.0, 0.0, -1.0]))]
    if h > 0:
        bot = top + np.array([0.0, 0.0, h])
        for i, nrm in enumerate(([1.0, 0, 0], [0, 1.0, 0], [-1.0, 0, 0], [0, -1.0, 0])):
            j = (i + 1) % 4
            quad = np.array([top[i], top[j], bot[j], bot[i]])
            faces.append((quad, np.asarray(nrm, dtype=np.float64)))
    return faces


def disc_polygon(radius_m: float, n: int = 32) -> NDArray[np.float64]:
    a = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    return np.column_stack((radius_m * np.cos(a), radius_m * np.sin(a), np.zeros(n)))


# ---------------------------------------------------------------------------------------------
# Scene objects
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Object:
    """A rigid object: faces in its own frame, placed at (north, east, down) with a yaw,
    optionally moving horizontally."""

    name: str
    faces: tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...]
    colour_bgr: tuple[int, int, int]
    north_m: float
    east_m: float
    down_m: float
    yaw_deg: float
    velocity_ne_mps: tuple[float, float] = (0.0, 0.0)

    def pose_ned(self, time_ns: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        dt = (time_ns - EPOCH_NS) / 1e9
        t = np.array([self.north_m + self.velocity_ne_mps[0] * dt,
                      self.east_m + self.velocity_ne_mps[1] * dt, self.down_m])
        return rot_z(math.radians(self.yaw_deg)), t


def _distractor_object(i: int, d: DistractorConfig, seed: int) -> _Object:
    rng = _seed_rng(seed, "distractor", str(i))
    yaw = float(rng.uniform(-180.0, 180.0))
    colour = tuple(int(c) for c in d.color_bgr)
    if d.kind in ("box", "moving_box"):
        faces = box_faces(d.size_m, d.size_m, d.height_m)
        down = -d.height_m
    elif d.kind == "disc":
        faces = [(disc_polygon(d.size_m / 2.0), np.array([0.0, 0.0, -1.0]))]
        down = -0.002
    else:  # stripe: a painted line on the ground, size_m long, size_m/8 wide
        faces = [(box_faces(d.size_m, max(0.02, d.size_m / 8.0), 0.0)[0][0],
                  np.array([0.0, 0.0, -1.0]))]
        down = -0.002
    vel = d.velocity_ne_mps if d.kind == "moving_box" else (0.0, 0.0)
    return _Object(f"{d.kind}{i}", tuple(faces), colour, d.north_m, d.east_m, down, yaw,
                   (float(vel[0]), float(vel[1])))


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


def _homography_inv(H: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.asarray(np.linalg.inv(H), dtype=np.float64)


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

    def __init__(self, simulation: SimulationConfig | None, target: TargetConfig, *,
                 seed: int | None = None, extent_m: float | None = None,
                 base_texel_m: float = 0.05, truth_history: int = 2000) -> None:
        self.simulation = simulation or SimulationConfig()
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
        self.textures: GroundTextures = ground_textures(
            sim.ground_texture, self.seed, float(extent_m), base_texel_m)
        rng = _seed_rng(self.seed, "sun")
        az = math.radians(rng.uniform(-180.0, 180.0))
        el = math.radians(rng.uniform(35.0, 65.0))
        # Unit vector from the ground towards the sun, NED.
        self.sun_ned = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az),
                                 -math.sin(el)])
        colour = target.color_bgr if target.color_bgr is not None else DEFAULT_TARGET_BGR
        self.target_colour_bgr: tuple[int, int, int] = (int(colour[0]), int(colour[1]),
                                                         int(colour[2]))
        self._target = _Object("target", tuple(box_faces(target.length_m, target.width_m,
                                                         target.height_m)),
                               self.target_colour_bgr, sim.target_north_m, sim.target_east_m,
                               -target.height_m, sim.target_yaw_deg)
        self._objects = [_distractor_object(i, d, self.seed)
                         for i, d in enumerate(sim.distractors)]
        self._ctx: dict[tuple[object, ...], _CameraCtx] = {}
        self._const: dict[tuple[object, ...], tuple[NDArray[np.uint8], NDArray[np.uint8]]] = {}
        self._bgra: dict[int, NDArray[np.uint8] | None] = {}  # base levels with 4 channels
        self._lock = threading.Lock()
        self._truth: dict[str, OrderedDict[int, GroundTruth]] = {}
        self._truth_history = int(truth_history)

    # -- target ---------------------------------------------------------------------------------
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
        rng = _seed_rng(self.seed, "camera", model.camera_id)
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
            nrng = _seed_rng(self.seed, "noise", model.camera_id)
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
            maps = (m1, m2)
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
               attitude_q: Sequence[float], timestamp_ns: int
               ) -> tuple[NDArray[np.uint8], GroundTruth]:
        """Render what ``model`` sees from a vehicle at ``position_ned_m`` with attitude
        ``attitude_q`` (body FRD -> NED), with the world as it is at ``timestamp_ns``.

        Returns the BGR image (H, W, 3) uint8 and its :class:`GroundTruth` (``timestamp_ns``
        and ``render_time_ns`` both set to ``timestamp_ns``).
        """
        ctx = self._camera_ctx(model)
        R_nb = quat_to_R(attitude_q)
        p = np.asarray(position_ned_m, dtype=np.float64)
        if p.shape != (3,) or not np.isfinite(p).all():
            raise ValueError(f"position_ned_m: must be 3 finite numbers, got {position_ned_m!r}")
        C = p + R_nb @ np.asarray(model.mount.lever_arm_m, dtype=np.float64)
        R_no = R_nb @ ctx.R_body_optical_true  # optical -> NED
        R_on = R_no.T
        W, H = model.width_px, model.height_px
        img = np.empty((H, W, 3), np.uint8)
        self._render_ground(img, ctx.K_true, R_on, C)
        self._render_sky(img, ctx.K_true, R_no)
        self._render_objects(img, ctx.K_true, R_on, C, int(timestamp_ns))
        gain = self.simulation.light_gain
        if gain != 1.0:
            cv2.convertScaleAbs(img, dst=img, alpha=gain)
        if ctx.undistort_maps is not None:
            img = cv2.remap(img, ctx.undistort_maps[0], ctx.undistort_maps[1], cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_REPLICATE)
        if ctx.noise_pos is not None and ctx.noise_neg is not None:
            h = zlib.crc32(f"{model.camera_id}/{int(timestamp_ns)}".encode()) ^ self.seed
            oy, ox = (h % ctx.noise_pad), ((h // ctx.noise_pad) % ctx.noise_pad)
            cv2.add(img, ctx.noise_pos[oy:oy + H, ox:ox + W], dst=img)
            cv2.subtract(img, ctx.noise_neg[oy:oy + H, ox:ox + W], dst=img)
        truth = self._ground_truth(ctx, R_on, C, int(timestamp_ns))
        return img, truth

    # ground --------------------------------------------------------------------------------
    def _render_ground(self, img: NDArray[np.uint8], K: NDArray[np.float64],
                       R_on: NDArray[np.float64], C: NDArray[np.float64]) -> None:
        tex = self.textures
        H, W = img.shape[:2]
        t = -R_on @ C
        # ground (north, east, 1) -> pixel
        Hg = K @ np.column_stack((R_on[:, 0], R_on[:, 1], t))
        if abs(np.linalg.det(Hg)) < 1e-12:  # camera on the plane: nothing sensible to show
            img[:] = np.asarray(tex.base_mean_bgr, np.uint8)
            return
        G = _homography_inv(Hg)  # pixel -> ground
        Kinv = np.linalg.inv(K)
        down = (R_on.T @ Kinv)[2]  # ray's down component, linear in (u, v, 1)
        levels = self._band_levels(G, down, W, H)
        for r0, r1, lb, ld in levels:
            self._render_band(img, G, r0, r1, lb, ld, tex)
        self._render_haze(img, G, down, C)

    def _render_haze(self, img: NDArray[np.uint8], G: NDArray[np.float64],
                     down: NDArray[np.float64], C: NDArray[np.float64]) -> None:
        """Aerial perspective on far ground: blend towards the horizon colour with
        ``1 - exp(-distance / HAZE_VISIBILITY_M)`` and fade the texture to its mean colour
        near the edge of the textured square, so neither the edge nor the horizon is a
        hard line. Only rows that reach ``HAZE_MIN_M`` are touched (cheap at close range)."""
        H, W = img.shape[:2]
        half = self.textures.extent_m / 2.0
        step = 8
        rows = np.arange(0, H + step - 1, step, dtype=np.float64).clip(0, H - 1)
        cols = np.array([0.0, (W - 1) / 2.0, W - 1.0])
        uu, vv = np.meshgrid(cols, rows)
        pts = np.stack((uu.ravel(), vv.ravel(), np.ones(uu.size)))
        g = G @ pts
        dn = down @ pts
        with np.errstate(divide="ignore", invalid="ignore"):
            ne = g[:2] / g[2]
        dist = np.where(dn > 1e-9, np.hypot(ne[0] - C[0], ne[1] - C[1]), np.inf)
        far = (dist.reshape(len(rows), 3).max(axis=1) >= min(HAZE_MIN_M, 0.7 * half))
        if not far.any():
            return
        r1 = min(H, int(rows[np.nonzero(far)[0].max()]) + step)  # far rows are at the top
        # The factors are smooth: compute them on a 4x coarser grid, then upsample.
        k = 4
        hs, ws = (r1 + k - 1) // k + 1, (W + k - 1) // k + 1
        vv2, uu2 = np.mgrid[0:hs, 0:ws].astype(np.float64) * k
        gx = G[0, 0] * uu2 + G[0, 1] * vv2 + G[0, 2]
        gy = G[1, 0] * uu2 + G[1, 1] * vv2 + G[1, 2]
        gz = G[2, 0] * uu2 + G[2, 1] * vv2 + G[2, 2]
        dz = down[0] * uu2 + down[1] * vv2 + down[2]
        ground = dz > 0
        gz = np.where(np.abs(gz) < 1e-12, 1e-12, gz)
        n, e = gx / gz, gy / gz
        d = np.where(ground, np.hypot(n - C[0], e - C[1]), 1e9)
        haze = (1.0 - np.exp(-d / HAZE_VISIBILITY_M)) * HAZE_MAX
        edge = np.clip((np.maximum(np.abs(n), np.abs(e)) - 0.7 * half) / (0.3 * half), 0, 1)
        edge = np.where(ground, edge * edge * (3 - 2 * edge), 1.0)
        # grid point (i, j) is pixel (k j, k i): an affine upsampling, then crop
        M = np.array([[1.0 / k, 0.0, 0.0], [0.0, 1.0 / k, 0.0]])
        flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
        edge_full = None
        if edge.max() > 0.0:  # else the fade is 0 everywhere: blending with it is the identity
            edge_full = cv2.warpAffine(edge.astype(np.float32), M, (W, r1), flags=flags,
                                       borderMode=cv2.BORDER_REPLICATE)
        haze_full = cv2.warpAffine(haze.astype(np.float32), M, (W, r1), flags=flags,
                                   borderMode=cv2.BORDER_REPLICATE)
        mean, horizon = self._haze_colours(H, W)
        # the edge fade leaves a row untouched where its weight is 0 everywhere (near ground)
        re = 0
        if edge_full is not None:
            rows_e = np.flatnonzero(edge_full.max(axis=1) > 0.0)
            re = int(rows_e[-1]) + 1 if len(rows_e) else 0
        if re > 0 and edge_full is not None:
            img[:re] = cv2.blendLinear(img[:re], mean[:re], 1.0 - edge_full[:re], edge_full[:re])
        img[:r1] = cv2.blendLinear(img[:r1], horizon[:r1], 1.0 - haze_full, haze_full)

    def _haze_colours(self, H: int, W: int) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        """Constant images of the ground's mean colour and the horizon colour (cached)."""
        key = ("haze", H, W)
        with self._lock:
            found = self._const.get(key)
        if found is None:
            mean = np.empty((H, W, 3), np.uint8)
            mean[:] = np.asarray(np.round(self.textures.base_mean_bgr), np.uint8)
            horizon = np.empty((H, W, 3), np.uint8)
            horizon[:] = np.asarray(SKY_HORIZON_BGR, np.uint8)
            found = (mean, horizon)
            with self._lock:
                self._const[key] = found
        return found

    def _band_levels(self, G: NDArray[np.float64], down: NDArray[np.float64], W: int, H: int
                     ) -> list[tuple[int, int, int, int]]:
        """Row bands with the same (base level, detail level); detail -1 = none."""
        tex = self.textures
        step = 8
        rows = np.arange(0, H, step, dtype=np.float64) + step / 2.0
        cols = np.array([0.0, (W - 1) / 2.0, W - 1.0])
        uu, vv = np.meshgrid(cols, rows)
        pts = np.stack((uu.ravel(), vv.ravel(), np.ones(uu.size)))
        g = G @ pts
        valid = (down @ pts) > 1e-6
        gz = np.where(np.abs(g[2]) < 1e-12, 1e-12, g[2])
        # |det J| of the pixel -> ground map for a homography: det(G) / g_z^3.
        detJ = np.abs(np.linalg.det(G) / gz ** 3)
        fp = np.sqrt(detJ)
        fp = np.where(valid, fp, np.inf).reshape(len(rows), len(cols))
        fp_row = np.median(fp, axis=1)  # inf where most of the row is sky
        nb = len(tex.base)
        nd = len(tex.detail_tiled)
        bands: list[tuple[int, int, int, int]] = []
        for i, f in enumerate(fp_row.tolist()):
            if not math.isfinite(f):
                lb, ld = nb - 1, -1
            else:
                lb = min(max(math.floor(math.log2(max(f, 1e-9) / tex.base_texel_m) + 0.5), 0),
                         nb - 1)
                ld_f = math.floor(math.log2(max(f, 1e-9) / tex.detail_texel_m) + 0.5)
                ld = int(max(0, ld_f)) if ld_f < nd else -1
            r0 = i * step
            r1 = min(H, r0 + step)
            if bands and bands[-1][2] == lb and bands[-1][3] == ld:
                bands[-1] = (bands[-1][0], r1, lb, ld)
            else:
                bands.append((r0, r1, lb, ld))
        return bands

    def _render_band(self, img: NDArray[np.uint8], G: NDArray[np.float64], r0: int, r1: int,
                     lb: int, ld: int, tex: GroundTextures) -> None:
        W = img.shape[1]
        h = r1 - r0
        shift = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, float(r0)], [0.0, 0.0, 1.0]])
        s = tex.base_texel_m * 2 ** lb
        # ground (n, e, 1) -> texel (col, row, 1) of base level lb
        ground_to_tex = np.array([[0.0, 1.0 / s, -tex.origin_east_m / s - 0.5],
                                  [-1.0 / s, 0.0, tex.origin_north_m / s - 0.5],
                                  [0.0, 0.0, 1.0]])
        M = ground_to_tex @ G @ shift  # band pixel -> texel
        band = img[r0:r1]
        mean = tex.base_mean_bgr
        src4 = self._base_bgra(lb)
        if src4 is not None:
            # same interpolation per channel; OpenCV's 4-channel path is ~2x faster
            band4 = cv2.warpPerspective(src4, M, (W, h),
                                        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                        borderMode=cv2.BORDER_CONSTANT,
                                        borderValue=(*mean, 255.0))
            cv2.cvtColor(band4, cv2.COLOR_BGRA2BGR, dst=band)
        else:
            cv2.warpPerspective(tex.base[lb], M, (W, h), dst=band,
                                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=mean)
        if ld < 0:
            return
        src = tex.detail_tiled[ld]
        sd = tex.detail_texel_m * 2 ** ld
        period = tex.detail_period_px >> ld
        g2t = np.array([[0.0, 1.0 / sd, 0.0], [-1.0 / sd, 0.0, 0.0], [0.0, 0.0, 1.0]])
        Md = g2t @ G @ shift
        corners = np.array([[0, 0, 1], [W - 1, 0, 1], [0, h - 1, 1], [W - 1, h - 1, 1]], float).T
        q = Md @ corners
        if (q[2] * np.sign(q[2][0]) <= 0).any():
            return
        q = q[:2] / q[2]
        lo = np.floor(q.min(axis=1) / period) * period
        span = q.max(axis=1) - lo
        if (span >= src.shape[0] - 2).any():
            return  # footprint wider than the pre-tiled detail: skip detail in this band
        Md = np.array([[1.0, 0.0, -lo[0]], [0.0, 1.0, -lo[1]], [0.0, 0.0, 1.0]]) @ Md
        d = cv2.warpPerspective(src, Md, (W, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=128)
        cv2.multiply(band, cv2.cvtColor(d, cv2.COLOR_GRAY2BGR), dst=band, scale=1.0 / 128.0)

    def warm_up(self) -> None:
        """Build the 4-channel base levels now (~50 ms for a 200 m world) rather than inside
        the first frames of a timed flight."""
        for level in range(len(self.textures.base)):
            self._base_bgra(level)

    def _base_bgra(self, level: int) -> NDArray[np.uint8] | None:
        """Base level ``level`` with a 4th channel (built on first use, kept per world), or
        None when it would exceed ``BGRA_LEVEL_BUDGET_BYTES`` (then the 3-channel path)."""
        with self._lock:
            found = self._bgra.get(level)
        if found is not None or level in self._bgra:
            return found
        src = self.textures.base[level]
        arr = None
        if src.nbytes * 4 // 3 <= BGRA_LEVEL_BUDGET_BYTES:
            arr = cv2.cvtColor(src, cv2.COLOR_BGR2BGRA)
            arr.flags.writeable = False
        with self._lock:
            self._bgra[level] = arr
        return arr

    # sky -----------------------------------------------------------------------------------
    def _render_sky(self, img: NDArray[np.uint8], K: NDArray[np.float64],
                    R_no: NDArray[np.float64]) -> None:
        H, W = img.shape[:2]
        Kinv = np.linalg.inv(K)
        down = (R_no @ Kinv)[2]  # d-component of the ray through (u, v, 1), linear
        rect = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5]])
        # sky: down(u, v) <= 0  <=>  -down[:2] . (u, v) >= down[2]
        sky = clip_polygon(rect, -down[:2], float(down[2]))
        if polygon_area(sky) < 0.5:
            return
        y0 = max(0, int(math.floor(sky[:, 1].min())))
        y1 = min(H, int(math.ceil(sky[:, 1].max())) + 1)
        # the mask of the sky rows only (an integer shift does not change the rasterisation)
        mask = np.zeros((y1 - y0, W), np.uint8)
        pts = np.round(sky * 16).astype(np.int32) - np.array([0, 16 * y0], np.int32)
        cv2.fillConvexPoly(mask, pts, 255, cv2.LINE_8, 4)
        # elevation ~ -down / |ray|: gradient from horizon colour to zenith colour; each ray
        # component is a linear function of (u, v): three planes, broadcast row x column
        M = (R_no @ Kinv).astype(np.float32)
        uu = np.arange(W, dtype=np.float32)[None, :]
        vv = np.arange(y0, y1, dtype=np.float32)[:, None]
        rx = uu * M[0, 0] + (vv * M[0, 1] + M[0, 2])
        ry = uu * M[1, 0] + (vv * M[1, 1] + M[1, 2])
        rz = uu * M[2, 0] + (vv * M[2, 1] + M[2, 2])
        elev = -rz / np.sqrt(rx * rx + ry * ry + rz * rz)
        t = np.clip(elev * np.float32(2.0), 0.0, 1.0) ** np.float32(0.6)
        hz = np.asarray(SKY_HORIZON_BGR, np.float32)
        zn = np.asarray(SKY_ZENITH_BGR, np.float32)
        sky_img = (hz + (zn - hz) * t[..., None]).astype(np.uint8)
        np.copyto(img[y0:y1], sky_img, where=mask[:, :, None] > 0)

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
                       R_on: NDArray[np.float64], C: NDArray[np.float64], obj: _Object,
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
