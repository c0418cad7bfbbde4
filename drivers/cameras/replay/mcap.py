"""One camera's frames in an MCAP flight recording (``run --record FILE.mcap``), for the
``replay`` camera: the stamps, sequence numbers and exposures of its companion channel
``/camera/<id>/frame`` read at once, the ``foxglove.CompressedImage`` images of
``/camera/<id>/image`` decoded one at a time, in order, as the replay asks for them (a long
flight is never held in memory)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from numpy.typing import NDArray

from eaglemission.errors import ConfigError
from eaglemission.recording.mcap_reader import messages
from eaglemission.recording.mcap_writer import TOPIC_FRAME, TOPIC_IMAGE


class McapFrames:
    """Frame ``k`` of camera ``camera_id``: ``entries[k]`` = (seq, timestamp_ns, exposure_s),
    :meth:`image` its pixels (BGR)."""

    def __init__(self, path: Path, camera_id: str, *, where: str) -> None:
        self.path, self.camera_id = path, camera_id
        frame_topic = TOPIC_FRAME.format(camera_id)
        self.entries: list[tuple[int, int, float]] = []
        cameras: set[str] = set()
        self.end_ns = 0
        try:
            for topic, msg in messages(path):
                self.end_ns = max(self.end_ns, int(msg.log_time))
                if topic == frame_topic:
                    info = json.loads(msg.data)
                    self.entries.append((int(info["seq"]), int(info["timestamp_ns"]),
                                         float(info.get("exposure_s", 0.0))))
                elif topic.startswith("/camera/") and topic.endswith("/frame"):
                    cameras.add(topic.split("/")[2])
        except (OSError, ValueError, KeyError) as exc:
            raise ConfigError(f"{where}: cannot read {str(path)!r} as a recording: {exc}") from exc
        if not self.entries:
            raise ConfigError(f"{where}: {str(path)!r} holds no frames of camera "
                              f"{camera_id!r} (recorded cameras: {sorted(cameras)})")
        self._images: Iterator[tuple[int, bytes]] | None = None
        self._next = 0

    def _iter(self) -> Iterator[tuple[int, bytes]]:
        topic = TOPIC_IMAGE.format(self.camera_id)
        k = 0
        for t, msg in messages(self.path):
            if t == topic:
                yield k, msg.data
                k += 1

    def image(self, k: int) -> NDArray[Any] | None:
        """The decoded image of frame ``k`` (None: missing or undecodable); frames are read
        forwards, so going back starts the file over."""
        if self._images is None or k < self._next:
            self._images = self._iter()
        for i, data in self._images:
            self._next = i + 1
            if i == k:
                buf = np.frombuffer(CompressedImage.FromString(data).data, dtype=np.uint8)
                return cv2.imdecode(buf, cv2.IMREAD_COLOR) if buf.size else None
        return None
