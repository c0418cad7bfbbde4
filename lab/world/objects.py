"""Geometry and objects of the synthetic world: polygon clipping, boxes and discs, seeded
random rotations, the scene's rigid objects (target and distractors)."""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass

import cv2
import numpy as np
from eaglemission.lab.world.synthetic import DistractorConfig
from numpy.typing import NDArray

from eaglemission.geometry import rot_z

NEAR_PLANE_M = 0.02
EPOCH_NS = 1_000_000_000  # VirtualTimeLoop starts at 1 s: moving distractors start there


def seed_rng(seed: int, *salt: str) -> np.random.RandomState:
    """A RandomState for one purpose (``salt``) of a world seed."""
    h = zlib.crc32("/".join(salt).encode()) ^ ((int(seed) * 2654435761) & 0xFFFFFFFF)
    return np.random.RandomState(h & 0xFFFFFFFF)


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


@dataclass(frozen=True)
class SceneObject:
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


def distractor_object(i: int, d: DistractorConfig, seed: int) -> SceneObject:
    rng = seed_rng(seed, "distractor", str(i))
    yaw = float(rng.uniform(-180.0, 180.0))
    colour = (int(d.color_bgr[0]), int(d.color_bgr[1]), int(d.color_bgr[2]))
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
    return SceneObject(f"{d.kind}{i}", tuple(faces), colour, d.north_m, d.east_m, down, yaw,
                   (float(vel[0]), float(vel[1])))
