"""Camera calibration files: OpenCV FileStorage (YAML or XML) and ROS ``camera_info`` YAML.

Both give the pinhole matrix ``K`` (3x3, pixels), OpenCV-ordered distortion coefficients
``(k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4[, tx, ty]]]])`` and the image size they were
calibrated at. Fields read:

================================  ==========================================================
OpenCV FileStorage (``%YAML:1.0``  ``camera_matrix`` (``!!opencv-matrix`` 3x3),
header, or XML ``<opencv_storage>``) ``distortion_coefficients`` (1xN or Nx1), ``image_width``,
                                   ``image_height`` (as written by OpenCV's calibration sample)
ROS ``camera_info`` YAML           ``camera_matrix: {rows: 3, cols: 3, data: [9]}``,
(``camera_calibration`` output)    ``distortion_coefficients: {rows, cols, data}``,
                                   ``distortion_model`` (``plumb_bob`` or
                                   ``rational_polynomial``), ``image_width``, ``image_height``
================================  ==========================================================

Aliases accepted for the matrices: ``K`` / ``cameraMatrix`` and ``D`` / ``dist_coeffs`` /
``distCoeffs``. Every problem raises :class:`~eaglemission.errors.ConfigError` naming the file
and the field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from eaglemission.errors import ConfigError
from eaglemission.types import Mat3

_K_KEYS = ("camera_matrix", "K", "cameraMatrix")
_D_KEYS = ("distortion_coefficients", "D", "dist_coeffs", "distCoeffs")
_DIST_LENGTHS = (0, 4, 5, 8, 12, 14)
_ROS_MODELS = {"plumb_bob": (5,), "rational_polynomial": (8,), "": _DIST_LENGTHS}


@dataclass(frozen=True)
class Calibration:
    """Intrinsics read from a calibration file."""

    K: Mat3
    distortion: tuple[float, ...]
    width_px: int
    height_px: int
    source: str = ""
    camera_name: str = ""

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])


def load_calibration(path: str | Path) -> Calibration:
    """Read a calibration file (format detected from its content).

    Raises
    ------
    ConfigError
        File missing or unreadable, unknown format, or a field missing or invalid; the message
        names the file and the field and says how to fix it.
    """
    p = Path(path)
    src = str(p)
    if not p.is_file():
        raise ConfigError(f"calibration file not found: check the path {src!r}", source=src)
    try:
        head = p.read_bytes()[:512].lstrip()
    except OSError as exc:
        raise ConfigError(f"cannot read the calibration file: {exc}", source=src) from None
    if head.startswith(b"%YAML") or head.startswith(b"<?xml") or head.startswith(b"<opencv_storage"):
        fields = _read_filestorage(p)
    else:
        fields = _read_ros_yaml(p)
    return _validate(fields, src)


# ---------------------------------------------------------------------------------------------
# Readers: both return {"K": ndarray|None, "D": ndarray|None, "width": Any, "height": Any, ...}
# ---------------------------------------------------------------------------------------------
def _read_filestorage(p: Path) -> dict[str, Any]:
    src = str(p)
    try:
        fs = cv2.FileStorage(src, cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        raise ConfigError(f"not a readable OpenCV FileStorage file: {str(exc).strip()}", source=src) from None
    if not fs.isOpened():
        raise ConfigError("not a readable OpenCV FileStorage file (YAML/XML)", source=src)
    try:
        out: dict[str, Any] = {"format": "opencv"}
        for slot, keys in (("K", _K_KEYS), ("D", _D_KEYS)):
            out[slot] = None
            out[slot + "_key"] = keys[0]
            for key in keys:
                node = fs.getNode(key)
                if not node.empty():
                    out[slot + "_key"] = key
                    if node.isMap() and not node.getNode("data").empty():
                        mat = node.mat()
                    elif node.isSeq():
                        mat = np.array([node.at(i).real() for i in range(node.size())])
                    else:
                        mat = node.mat()
                    out[slot] = None if mat is None else np.asarray(mat, dtype=np.float64)
                    if out[slot] is None:
                        out[slot] = "unreadable"
                    break
        for slot, key in (("width", "image_width"), ("height", "image_height")):
            node = fs.getNode(key)
            out[slot] = None if node.empty() else node.real()
        name = fs.getNode("camera_name")
        out["name"] = name.string() if not name.empty() and name.isString() else ""
        return out
    finally:
        fs.release()


def _read_ros_yaml(p: Path) -> dict[str, Any]:
    src = str(p)
    try:
        data = yaml.safe_load(p.read_text("utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ConfigError(
            f"neither OpenCV FileStorage (no %YAML:1.0 header / XML) nor valid ROS camera_info "
            f"YAML: {exc}", source=src) from None
    if not isinstance(data, dict):
        raise ConfigError(
            f"must be a mapping with camera_matrix, distortion_coefficients, image_width, "
            f"image_height; got {type(data).__name__}", source=src)
    out: dict[str, Any] = {"format": "ros", "name": str(data.get("camera_name", "") or "")}
    for slot, keys in (("K", _K_KEYS), ("D", _D_KEYS)):
        out[slot] = None
        out[slot + "_key"] = keys[0]
        for key in keys:
            if key in data:
                out[slot + "_key"] = key
                out[slot] = _ros_matrix(data[key], key, src)
                break
    out["width"] = data.get("image_width")
    out["height"] = data.get("image_height")
    model = data.get("distortion_model", "")
    if model not in _ROS_MODELS:
        raise ConfigError(
            f"distortion_model: {model!r} is not supported (OpenCV pinhole models only: "
            f"plumb_bob, rational_polynomial; for fisheye/equidistant lenses calibrate with a "
            f"pinhole model)", source=src)
    out["model"] = model
    return out


def _ros_matrix(node: Any, key: str, src: str) -> np.ndarray:
    if isinstance(node, dict):
        if "data" not in node:
            raise ConfigError(f"{key}.data: missing: add the matrix entries as a list", source=src)
        data = node["data"]
        rows, cols = node.get("rows"), node.get("cols")
    else:
        data, rows, cols = node, None, None
    try:
        arr = np.asarray(data, dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"{key}.data: must be a list of numbers, got {data!r:.60}", source=src) from None
    if rows is not None and cols is not None:
        if not (isinstance(rows, int) and isinstance(cols, int)) or rows * cols != arr.size:
            raise ConfigError(
                f"{key}: rows x cols = {rows} x {cols} does not match {arr.size} data values",
                source=src)
        arr = arr.reshape(rows, cols)
    return arr


# ---------------------------------------------------------------------------------------------
# Validation
# ---------------------------------------------------------------------------------------------
def _positive_int(value: Any, key: str, src: str) -> int:
    if value is None:
        raise ConfigError(f"{key}: missing: add the image size the camera was calibrated at", source=src)
    if isinstance(value, bool):
        raise ConfigError(f"{key}: must be a positive integer, got {value!r}", source=src)
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{key}: must be a positive integer, got {value!r}", source=src) from None
    if not (math.isfinite(f) and f > 0 and f == int(f)):
        raise ConfigError(f"{key}: must be a positive integer, got {value!r}", source=src)
    return int(f)


def _validate(fields: dict[str, Any], src: str) -> Calibration:
    K = fields.get("K")
    kkey = fields.get("K_key", "camera_matrix")
    if K is None:
        raise ConfigError(
            f"{kkey}: missing: add the 3x3 camera matrix (also accepted: {', '.join(_K_KEYS[1:])})",
            source=src)
    if isinstance(K, str):
        raise ConfigError(f"{kkey}: unreadable matrix (write it as !!opencv-matrix rows/cols/dt/data)",
                          source=src)
    K = np.asarray(K, dtype=np.float64)
    if K.size == 9:
        K = K.reshape(3, 3)
    if K.shape != (3, 3):
        raise ConfigError(f"{kkey}: must be 3x3, got shape {K.shape}", source=src)
    if not np.isfinite(K).all():
        raise ConfigError(f"{kkey}: contains NaN or inf", source=src)
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise ConfigError(f"{kkey}: fx and fy must be > 0, got fx={K[0, 0]:g}, fy={K[1, 1]:g}",
                          source=src)
    if not (np.allclose(K[2], (0.0, 0.0, 1.0)) and K[1, 0] == 0.0):
        raise ConfigError(f"{kkey}: must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}",
                          source=src)
    D = fields.get("D")
    dkey = fields.get("D_key", "distortion_coefficients")
    if D is None:
        raise ConfigError(
            f"{dkey}: missing: add the distortion coefficients (an empty list or zeros if none)",
            source=src)
    if isinstance(D, str):
        raise ConfigError(f"{dkey}: unreadable matrix", source=src)
    D = np.asarray(D, dtype=np.float64).reshape(-1)
    if D.size not in _DIST_LENGTHS:
        raise ConfigError(
            f"{dkey}: OpenCV takes 4, 5, 8, 12 or 14 coefficients, got {D.size}", source=src)
    if not np.isfinite(D).all():
        raise ConfigError(f"{dkey}: contains NaN or inf", source=src)
    model = fields.get("model", "")
    if model and D.size not in _ROS_MODELS[model]:
        raise ConfigError(
            f"{dkey}: distortion_model {model} takes {_ROS_MODELS[model][0]} coefficients, got {D.size}",
            source=src)
    width = _positive_int(fields.get("width"), "image_width", src)
    height = _positive_int(fields.get("height"), "image_height", src)
    cx, cy = K[0, 2], K[1, 2]
    if not (0 <= cx <= width and 0 <= cy <= height):
        raise ConfigError(
            f"{kkey}: principal point ({cx:g}, {cy:g}) lies outside the {width}x{height} image: "
            "check image_width/image_height and the matrix layout (row-major)", source=src)
    K.flags.writeable = False
    return Calibration(K=K, distortion=tuple(float(v) for v in D), width_px=width,
                       height_px=height, source=src, camera_name=str(fields.get("name", "")))


def save_calibration(path: str | Path, K: Mat3, distortion: tuple[float, ...] | np.ndarray,
                     width_px: int, height_px: int) -> None:
    """Write an OpenCV FileStorage file (YAML or XML by extension) that :func:`load_calibration`
    reads back."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    try:
        fs.write("image_width", int(width_px))
        fs.write("image_height", int(height_px))
        fs.write("camera_matrix", np.asarray(K, dtype=np.float64))
        fs.write("distortion_coefficients",
                 np.asarray(distortion, dtype=np.float64).reshape(1, -1))
    finally:
        fs.release()
