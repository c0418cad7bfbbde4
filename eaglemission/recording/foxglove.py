"""Foxglove views derived from a flight's records (docs/recording.md, "Foxglove panels").

Pure builders, called on the recorder's writer thread (never on the event loop):

* :func:`detection_annotations`: a ``detection`` log record -> ``foxglove.ImageAnnotations``
  (the MBR the mission used as a closed polyline, its score as text), stamped with the frame's
  mid-exposure so Foxglove's Image panel lays it over that very frame;
* :func:`saliency_image`: the detector's map, shrunk -> ``foxglove.CompressedImage`` (PNG, grey);
* :func:`vehicle_transform` / :func:`mount_transform`: ``foxglove.FrameTransforms``
  ``local_ned`` -> ``base_link`` (body FRD, the estimate) -> ``<camera id>`` (the optical frame
  the images and calibrations name), so the 3D panel places the vehicle and projects images;
* :func:`location_fix`: the vehicle's WGS-84 estimate -> ``foxglove.LocationFix`` (Map panel).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import cv2
import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from foxglove_schemas_protobuf.Point2_pb2 import Point2
from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation
from foxglove_schemas_protobuf.TextAnnotation_pb2 import TextAnnotation
from google.protobuf import descriptor_pb2
from numpy.typing import NDArray

from eaglemission.geometry import CameraModel, R_to_quat

FRAME_LOCAL = "local_ned"
"""The mission's local NED frame, origin at home (docs/conventions.md)."""
FRAME_BODY = "base_link"
"""The vehicle's body FRD frame, placed by the autopilot's estimate."""
SALIENCY_WIDTH_PX = 160
"""Width of the saliency thumbnail (its height keeps the frame's aspect)."""

_USED = Color(r=0.1, g=0.9, b=0.2, a=1.0)
_TEXT_BG = Color(r=0.0, g=0.0, b=0.0, a=0.6)
_WHITE = Color(r=1.0, g=1.0, b=1.0, a=1.0)


def file_descriptor_set(cls: Any) -> bytes:
    """The protobuf schema of a message class as MCAP wants it (a FileDescriptorSet)."""
    fds = descriptor_pb2.FileDescriptorSet()
    seen: set[str] = set()

    def add(fd: Any) -> None:
        for dep in fd.dependencies:
            if dep.name not in seen:
                seen.add(dep.name)
                add(dep)
        fd.CopyToProto(fds.file.add())

    add(cls.DESCRIPTOR.file)
    return bytes(fds.SerializeToString())


_FDS_CACHE: dict[str, bytes] = {}


def schema_of(cls: Any) -> bytes:
    """:func:`file_descriptor_set`, computed once per message type."""
    name = str(cls.DESCRIPTOR.full_name)
    fds = _FDS_CACHE.get(name)
    if fds is None:
        fds = _FDS_CACHE[name] = file_descriptor_set(cls)
    return fds


def calibration_message(model: CameraModel, camera_id: str, t_ns: int) -> CameraCalibration:
    K = np.asarray(model.K, dtype=np.float64)
    d = [float(v) for v in model.distortion]
    dist_model = "rational_polynomial" if len(d) > 5 else "plumb_bob"
    d += [0.0] * ((8 if len(d) > 5 else 5) - len(d))
    msg = CameraCalibration(frame_id=camera_id, width=int(model.width_px),
                            height=int(model.height_px), distortion_model=dist_model, D=d,
                            K=[float(v) for v in K.ravel()],
                            R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                            P=[K[0, 0], K[0, 1], K[0, 2], 0.0, K[1, 0], K[1, 1], K[1, 2], 0.0,
                               0.0, 0.0, 1.0, 0.0])
    msg.timestamp.FromNanoseconds(int(t_ns))
    return msg


def saliency_thumbnail(saliency: NDArray[Any], width_px: int = SALIENCY_WIDTH_PX
                       ) -> NDArray[np.uint8] | None:
    """The detector's map in [0, 1] as a small grey image (0..255, area-averaged); None for a
    map with non-finite values (the mission ignores such a map) or of no size."""
    m = np.asarray(saliency, dtype=np.float32)
    if m.ndim != 2 or m.size == 0 or not bool(np.isfinite(m).all()):
        return None
    h, w = m.shape
    tw = max(1, min(int(width_px), w))
    th = max(1, round(h * tw / w))
    small = cv2.resize(m, (tw, th), interpolation=cv2.INTER_AREA)
    return np.asarray(np.clip(small * 255.0 + 0.5, 0, 255), dtype=np.uint8)


def saliency_image(camera_id: str, t_ns: int, thumb: NDArray[np.uint8]) -> CompressedImage:
    ok, buf = cv2.imencode(".png", thumb)
    if not ok:
        raise ValueError(f"cannot encode the saliency thumbnail of {camera_id!r}")
    img = CompressedImage(frame_id=camera_id, data=buf.tobytes(), format="png")
    img.timestamp.FromNanoseconds(int(t_ns))
    return img


def detection_annotations(record: Mapping[str, Any]) -> ImageAnnotations:
    """The detection the mission used on a frame (none: an empty set, which clears the overlay)."""
    msg = ImageAnnotations()
    t_ns = int(record["frame_t_ns"])
    corners = record.get("corners_px")
    if corners:
        pts = PointsAnnotation(type=PointsAnnotation.Type.LINE_LOOP, outline_color=_USED,
                               thickness=2.0)
        pts.timestamp.FromNanoseconds(t_ns)
        for u, v in corners:
            pts.points.append(Point2(x=float(u), y=float(v)))
        msg.points.append(pts)
        u0 = min(float(c[0]) for c in corners)
        v0 = min(float(c[1]) for c in corners)
        score = record.get("score")
        label = "target" if score is None else f"target {float(score):.2f}"
        if record.get("colour_track"):
            label += " (colour)"
        txt = TextAnnotation(position=Point2(x=u0, y=max(0.0, v0 - 4.0)), text=label,
                             font_size=14.0, text_color=_WHITE, background_color=_TEXT_BG)
        txt.timestamp.FromNanoseconds(t_ns)
        msg.texts.append(txt)
    return msg


def _transform(t_ns: int, parent: str, child: str, translation: Sequence[float],
               q_wxyz: Sequence[float]) -> FrameTransform:
    tf = FrameTransform(parent_frame_id=parent, child_frame_id=child)
    tf.timestamp.FromNanoseconds(int(t_ns))
    tf.translation.x, tf.translation.y, tf.translation.z = (float(v) for v in translation)
    w, x, y, z = (float(v) for v in q_wxyz)
    tf.rotation.w, tf.rotation.x, tf.rotation.y, tf.rotation.z = w, x, y, z
    return tf


def _finite(values: Any, n: int) -> bool:
    try:
        return len(values) == n and all(math.isfinite(float(v)) for v in values)
    except (TypeError, ValueError):
        return False


def vehicle_transform(t_ns: int, state: Mapping[str, Any]) -> FrameTransforms | None:
    """``local_ned`` -> ``base_link`` from a ``/vehicle/state`` sample (None if not finite)."""
    pos, q = state.get("position_ned_m"), state.get("attitude_q")
    if not (_finite(pos, 3) and _finite(q, 4)):
        return None
    assert pos is not None and q is not None
    return FrameTransforms(transforms=[_transform(t_ns, FRAME_LOCAL, FRAME_BODY, pos, q)])


def mount_transform(t_ns: int, camera_id: str, model: CameraModel) -> FrameTransforms:
    """``base_link`` -> the camera's optical frame (its mount: lever arm and rotation)."""
    q = R_to_quat(model.mount.R_body_optical)
    return FrameTransforms(transforms=[_transform(t_ns, FRAME_BODY, camera_id,
                                                  model.mount.lever_arm_m, q)])


def location_fix(t_ns: int, state: Mapping[str, Any]) -> LocationFix | None:
    """The vehicle's WGS-84 estimate (``geodetic``), None when the sample has none."""
    geo = state.get("geodetic")
    if not isinstance(geo, Mapping):
        return None
    values: list[Any] = [geo.get(k) for k in ("latitude_deg", "longitude_deg", "altitude_amsl_m")]
    if not _finite(values, 3):
        return None
    lat, lon, alt = (float(v) for v in values)
    fix = LocationFix(frame_id=FRAME_BODY, latitude=lat, longitude=lon, altitude=alt,
                      position_covariance_type=LocationFix.PositionCovarianceType.UNKNOWN)
    fix.timestamp.FromNanoseconds(int(t_ns))
    return fix
