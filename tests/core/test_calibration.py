"""Calibration files: OpenCV FileStorage YAML/XML and ROS camera_info YAML."""

from __future__ import annotations

import numpy as np
import pytest

from eaglemission.config import CameraSection
from eaglemission.errors import ConfigError
from eaglemission.geometry.calibration import Calibration, load_calibration, save_calibration

K = np.array([[1203.5, 0.0, 641.2], [0.0, 1201.9, 478.7], [0.0, 0.0, 1.0]])
D = (-0.21, 0.08, 0.0012, -0.0007, -0.011)

ROS = """image_width: 1280
image_height: 960
camera_name: narrow
camera_matrix:
  rows: 3
  cols: 3
  data: [1203.5, 0, 641.2, 0, 1201.9, 478.7, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.21, 0.08, 0.0012, -0.0007, -0.011]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [1203.5, 0, 641.2, 0, 0, 1201.9, 478.7, 0, 0, 0, 1, 0]
"""

OPENCV_YAML = """%YAML:1.0
---
image_width: 1280
image_height: 960
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1203.5, 0., 641.2, 0., 1201.9, 478.7, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -0.21, 0.08, 0.0012, -0.0007, -0.011 ]
"""


def _check(cal: Calibration) -> None:
    np.testing.assert_allclose(cal.K, K)
    np.testing.assert_allclose(cal.distortion, D)
    assert (cal.width_px, cal.height_px) == (1280, 960)


@pytest.mark.parametrize("ext", ["yaml", "xml", "yml"])
def test_opencv_filestorage_round_trip(tmp_path, ext):
    p = tmp_path / f"cam.{ext}"
    save_calibration(p, K, D, 1280, 960)
    _check(load_calibration(p))


def test_opencv_yaml_text(tmp_path):
    p = tmp_path / "cam.yaml"
    p.write_text(OPENCV_YAML)
    _check(load_calibration(p))


def test_ros_camera_info(tmp_path):
    p = tmp_path / "narrow.yaml"
    p.write_text(ROS)
    cal = load_calibration(p)
    _check(cal)
    assert cal.camera_name == "narrow"


def test_camera_section_to_model_uses_calibration(tmp_path):
    p = tmp_path / "narrow.yaml"
    p.write_text(ROS)
    sec = CameraSection(type="synthetic", calibration_file=str(p))
    model = sec.to_model("narrow")
    np.testing.assert_allclose(model.K, K)
    assert model.distortion == D and model.width_px == 1280


@pytest.mark.parametrize(
    "mutate, field",
    [
        (lambda s: s.replace("image_width: 1280\n", ""), "image_width"),
        (lambda s: s.replace("image_height: 960", "image_height: -5"), "image_height"),
        (lambda s: s.replace("camera_matrix:", "cam_matrix:"), "camera_matrix"),
        (lambda s: s.replace("  data: [1203.5, 0, 641.2, 0, 1201.9, 478.7, 0, 0, 1]",
                             "  data: [1203.5, 0, 641.2, 0, 1201.9, 478.7, 0, 0]"), "camera_matrix"),
        (lambda s: s.replace("1203.5, 0, 641.2", "-3, 0, 641.2", 1), "camera_matrix"),
        (lambda s: s.replace("  cols: 5\n  data: [-0.21, 0.08, 0.0012, -0.0007, -0.011]",
                             "  cols: 3\n  data: [-0.21, 0.08, 0.0012]"), "distortion_coefficients"),
        (lambda s: s.replace("distortion_coefficients:", "dist:"), "distortion_coefficients"),
        (lambda s: s.replace("plumb_bob", "equidistant"), "distortion_model"),
        (lambda s: s.replace("641.2, 0, 1201.9", "6410.2, 0, 1201.9", 1), "principal point"),
    ],
)
def test_ros_bad_field_named(tmp_path, mutate, field):
    p = tmp_path / "bad.yaml"
    p.write_text(mutate(ROS))
    with pytest.raises(ConfigError) as exc:
        load_calibration(p)
    assert field in str(exc.value) and str(p) in str(exc.value)


def test_opencv_missing_matrix_named(tmp_path):
    p = tmp_path / "cam.yaml"
    p.write_text(OPENCV_YAML.replace("camera_matrix", "intrinsics"))
    with pytest.raises(ConfigError, match="camera_matrix"):
        load_calibration(p)


def test_missing_file_and_garbage(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_calibration(tmp_path / "nope.yaml")
    p = tmp_path / "garbage.yaml"
    p.write_text("- just\n- a list\n")
    with pytest.raises(ConfigError, match="mapping"):
        load_calibration(p)
    p.write_text("a: [unclosed\n")
    with pytest.raises(ConfigError, match="camera_info"):
        load_calibration(p)
