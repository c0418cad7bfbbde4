"""How the synthetic cameras draw a simulated arm's end (``SyntheticWorld.render``'s
``tool_body_m``): the gripper block around the tool point, the end of the Z slide above it (the
arm's stage sits behind the cameras, out of view) and, with a
:class:`~eaglemission.geometry.tool_marker.ToolMarker`, the ArUco marker on its white plate.
Nearer than anything on the ground, so drawn last: the slide, the block, the marker."""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import TYPE_CHECKING

import cv2
import numpy as np
from eaglemission.lab.world.objects import NEAR_PLANE_M, box_faces
from numpy.typing import NDArray

from eaglemission.geometry import quat_to_R
from eaglemission.geometry.tool_marker import ToolMarker, marker_axes_body, marker_corners_body
from eaglemission.perception.tool_marker import marker_image

if TYPE_CHECKING:
    from eaglemission.lab.world.render import SyntheticWorld

ARM_SLIDE_M = 0.06  # the visible end of the arm's Z slide above the gripper block
ARM_ROD_M = 0.015  # the slide's square section
ARM_BLOCK_M = 0.04  # the gripper block's side, centred on the tool point
ARM_ROD_BGR = (45, 45, 45)
ARM_BLOCK_BGR = (90, 90, 90)
PLATE_BGR = (235, 235, 235)


@functools.lru_cache(maxsize=4)
def _marker_bitmap(marker: ToolMarker) -> NDArray[np.uint8]:
    """The marker's black square, 96 px a side (warped onto its face in each frame)."""
    return marker_image(marker, 96)


def draw_arm(world: SyntheticWorld, img: NDArray[np.uint8], K: NDArray[np.float64],
             R_on: NDArray[np.float64], C: NDArray[np.float64],
             position_ned_m: Sequence[float], attitude_q: Sequence[float],
             tool_body_m: Sequence[float], marker: ToolMarker | None) -> None:
    """The arm's end with the tool at ``tool_body_m`` (body FRD), lit by ``world``'s sun."""
    H, W = img.shape[:2]
    R_nb = quat_to_R(attitude_q)
    p = np.asarray(position_ned_m, dtype=np.float64)
    tx, ty, tz = (float(v) for v in tool_body_m)
    parts = (((tx, ty, tz - ARM_BLOCK_M / 2 - ARM_SLIDE_M), ARM_ROD_M, ARM_SLIDE_M, ARM_ROD_BGR),
             ((tx, ty, tz - ARM_BLOCK_M / 2), ARM_BLOCK_M, ARM_BLOCK_M, ARM_BLOCK_BGR))
    for top, side, height, colour in parts:
        for verts, nrm in box_faces(side, side, height):
            v_ned = (verts + np.asarray(top)) @ R_nb.T + p
            n_ned = R_nb @ nrm
            if float(n_ned @ (C - v_ned[0])) <= 0.0:
                continue
            world._fill_face(img, K, R_on, C, v_ned, world.face_colour(colour, n_ned), W, H)
    if marker is not None:
        _draw_marker(world, img, K, R_on, C, R_nb, p, (tx, ty, tz), marker)


def _draw_marker(world: SyntheticWorld, img: NDArray[np.uint8], K: NDArray[np.float64],
                 R_on: NDArray[np.float64], C: NDArray[np.float64], R_nb: NDArray[np.float64],
                 p: NDArray[np.float64], tool: tuple[float, float, float],
                 marker: ToolMarker) -> None:
    """The marker on its white plate, lit like the face it lies on; only when the face is
    turned to the camera and the whole marker is in front of it."""
    H, W = img.shape[:2]
    n_ned = R_nb @ marker_axes_body(marker.facing)[:, 2]
    square = marker_corners_body(marker, tool) @ R_nb.T + p
    if float(n_ned @ (C - square[0])) <= 0.0:
        return
    if marker.plate_m > 0:
        plate = marker_corners_body(marker, tool, marker.plate_m) @ R_nb.T + p
        world._fill_face(img, K, R_on, C, plate, world.face_colour(PLATE_BGR, n_ned), W, H)
    cam = (square - C) @ R_on.T
    if not (cam[:, 2] > NEAR_PLANE_M).all():
        return
    uv = cam @ K.T
    uv = uv[:, :2] / uv[:, 2:3]
    u0, v0 = np.floor(uv.min(axis=0)).astype(int)
    u1, v1 = np.ceil(uv.max(axis=0)).astype(int) + 1
    if u1 <= 0 or v1 <= 0 or u0 >= W or v0 >= H or u1 - u0 > 2 * W or v1 - v0 > 2 * H:
        return
    a0, b0, a1, b1 = max(u0, 0), max(v0, 0), min(u1, W), min(v1, H)
    bitmap = _marker_bitmap(marker)
    n = float(bitmap.shape[0])
    src = np.array([[0, 0], [n, 0], [n, n], [0, n]], dtype=np.float32) - np.float32(0.5)
    dst = (uv - (a0, b0)).astype(np.float32)
    Hm = cv2.getPerspectiveTransform(src, dst)
    size = (a1 - a0, b1 - b0)
    face = cv2.warpPerspective(bitmap, Hm, size, flags=cv2.INTER_AREA,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    inside = cv2.warpPerspective(np.full_like(bitmap, 255), Hm, size, flags=cv2.INTER_AREA,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    roi = img[b0:b1, a0:a1].astype(np.float32)
    alpha = (inside.astype(np.float32) / 255.0)[..., None]
    lit = (face.astype(np.float32) * min(1.0, PLATE_BGR[0] / 255 * world.shade(n_ned)))[..., None]
    img[b0:b1, a0:a1] = np.clip(roi * (1 - alpha) + lit * alpha, 0, 255).astype(np.uint8)
