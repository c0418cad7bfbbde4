"""The cameras see the arm's tool: a correction for where they put the target relative to it.

A camera's target estimate goes through its mount calibration (a degree or two off is common:
at the half-metre of a grasp that is 1-2 cm) and, for an arm, the target is then compared with
the tool's read-back, which never went through the camera. When the tool carries a marker
(:class:`~eaglemission.geometry.tool_marker.ToolMarker`) the same camera measures the tool
too, through the same calibration: the difference between the tool's read-back and where the
camera sees it (``correction``, body FRD) is that calibration's error at the tool. Added to the
camera's target estimates, it puts the target where the camera would put it relative to the
tool, which is what the grasp needs (eye-to-hand servoing); what is left is the calibration's
error over the grasp distance between the tool and the target (about 6 mm for 2 deg at
0.175 m), not over the camera's range.

Per camera, the correction is the median, axis by axis, of the last :data:`WINDOW` sightings
(a sighting of more than ``max_correction_m`` is a misdetection, logged and dropped); it is
applied from :data:`MIN_SIGHTINGS` on.
"""

from __future__ import annotations

import bisect
import collections
import math
from collections.abc import Sequence

import numpy as np
from eaglemission.missions.log import MissionLog

from eaglemission.geometry import CameraModel, quat_to_R
from eaglemission.geometry.tool_marker import ToolMarker
from eaglemission.perception.tool_marker import (
    find_marker,
    marker_centre_cam,
    predicted_box_px,
    tool_body_from_marker,
)
from eaglemission.types import XYZ, Frame

WINDOW = 15
"""Sightings per camera the correction is the median of."""
MIN_SIGHTINGS = 3
"""The correction applies once a camera has seen the tool this often."""
MAX_CORRECTION_M = 0.05
"""A sighting this far from the read-back is not the tool's marker (or the calibration is not
one a correction should paper over)."""
HISTORY_S = 2.0
"""How far back the read-back is kept (a frame is processed at most this late)."""


class ToolSight:
    """Sightings of the tool's marker, per camera, and the correction they give (loop
    thread)."""

    def __init__(self, marker: ToolMarker, log: MissionLog, *,
                 max_correction_m: float = MAX_CORRECTION_M) -> None:
        self.marker, self.log = marker, log
        self.max_correction_m = max_correction_m
        self._readbacks: collections.deque[tuple[int, XYZ]] = collections.deque()
        self._samples: dict[str, collections.deque[XYZ]] = {}

    def record(self, timestamp_ns: int, tool_body_m: XYZ) -> None:
        """One read-back of the tool (every tick of the arm's loop)."""
        if not all(math.isfinite(v) for v in tool_body_m):
            return
        if self._readbacks and timestamp_ns <= self._readbacks[-1][0]:
            return
        self._readbacks.append((timestamp_ns, tool_body_m))
        while self._readbacks[0][0] < timestamp_ns - int(HISTORY_S * 1e9):
            self._readbacks.popleft()

    def readback_at(self, timestamp_ns: int) -> XYZ | None:
        """The read-back interpolated at a time inside the kept history (None outside)."""
        rb = self._readbacks
        if not rb or not rb[0][0] <= timestamp_ns <= rb[-1][0]:
            return None
        i = bisect.bisect_left([t for t, _ in rb], timestamp_ns)
        t1, p1 = rb[i]
        if t1 == timestamp_ns or i == 0:
            return p1
        t0, p0 = rb[i - 1]
        a = (timestamp_ns - t0) / (t1 - t0)
        return (p0[0] + a * (p1[0] - p0[0]), p0[1] + a * (p1[1] - p0[1]),
                p0[2] + a * (p1[2] - p0[2]))

    def observe(self, frame: Frame, model: CameraModel) -> XYZ | None:
        """Look for the marker where the read-back puts it in this frame; a sighting gives one
        correction sample (returned; None: not seen, or no read-back at the frame's time)."""
        tool = self.readback_at(frame.timestamp_ns)
        if tool is None:
            return None
        box = predicted_box_px(self.marker, model, tool)
        if box is None:
            return None
        image = np.asarray(frame.image)
        if image.ndim != 3 and image.ndim != 2:
            return None
        corners = find_marker(image, self.marker, box)
        centre = None if corners is None else marker_centre_cam(corners, self.marker, model)
        if centre is None:
            return None
        seen = tool_body_from_marker(centre, self.marker, model)
        c = (tool[0] - seen[0], tool[1] - seen[1], tool[2] - seen[2])
        cam = frame.camera_id
        if math.hypot(*c) > self.max_correction_m:
            self.log.write("fault_detected", what="tool_sighting", camera=cam,
                           text=f"the tool's marker seen {math.hypot(*c) * 100:.1f} cm from "
                           f"its read-back (> {self.max_correction_m * 100:.0f} cm)",
                           response="sighting ignored")
            return None
        samples = self._samples.setdefault(cam, collections.deque(maxlen=WINDOW))
        samples.append(c)
        self.log.write("tool_sight", camera=cam, frame_t_ns=frame.timestamp_ns,
                       readback_body_m=tool, seen_body_m=seen, sample_m=c,
                       correction_m=self.correction_m(cam), sightings=len(samples))
        return c

    def correction_m(self, camera_id: str) -> XYZ | None:
        """The camera's correction (body FRD): None until it has :data:`MIN_SIGHTINGS`."""
        samples = self._samples.get(camera_id)
        if samples is None or len(samples) < MIN_SIGHTINGS:
            return None
        m = np.median(np.asarray(samples), axis=0)
        return (float(m[0]), float(m[1]), float(m[2]))

    def corrected_ned_m(self, camera_id: str, attitude_q: Sequence[float], target_ned_m: XYZ
                        ) -> XYZ:
        """A target position the camera estimated, moved by its correction (unchanged without
        one): where that camera puts the target relative to the tool."""
        c = self.correction_m(camera_id)
        if c is None:
            return target_ned_m
        d = quat_to_R(attitude_q) @ np.asarray(c)
        return (target_ned_m[0] + float(d[0]), target_ned_m[1] + float(d[1]),
                target_ned_m[2] + float(d[2]))

